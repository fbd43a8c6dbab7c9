"""The canopy height model against a brute-force loop over cells, on a generated stand."""
from __future__ import annotations

import re

import numpy as np
import pytest

import gfjax.dtm
from gfjax.dtm.hag import height_above_ground
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud


def stand(seed=0):
    """Ground on a 30 x 20 m slope (0.5 m lattice, class 2) and 300 crown and stem points
    up to 25 m above it, a few just under the ground; the box leaves no cell empty but one."""
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.arange(0.25, 30, 0.5), np.arange(0.25, 20, 0.5))
    ground = np.column_stack([gx.ravel(), gy.ravel()])
    ground = ground[~((ground[:, 0] > 12) & (ground[:, 0] < 13) & (ground[:, 1] > 7) & (ground[:, 1] < 8))]
    trees = rng.uniform([0, 0], [30, 20], (300, 2))
    xy = np.concatenate([ground, trees]) + [700_000.0, 5_200_000.0]
    base = 300.0 + 0.1 * (xy[:, 0] - 700_000.0)
    above = np.concatenate([np.zeros(len(ground)), rng.uniform(-0.3, 25.0, len(trees))])
    cls = np.concatenate([np.full(len(ground), 2), np.full(len(trees), 5)]).astype(np.uint8)
    return np.column_stack([xy, base + above]), cls


def test_each_cell_holds_its_highest_height_above_ground():
    xyz, cls = stand()
    cloud = Cloud.from_xyz(xyz, classification=cls)
    raster = gfjax.dtm.chm(cloud, cls == 2, cell_m=2.0)
    xyz = cloud.xyz                                                # as stored (on the file's scale)
    heights = np.maximum(height_above_ground(xyz, cls == 2), 0.0)
    x0, y0 = raster.origin
    col = np.floor((xyz[:, 0] - x0) / 2.0).astype(int)
    row = np.floor((y0 - xyz[:, 1]) / 2.0).astype(int)
    want = np.full(raster.shape, raster.nodata)
    for r, c, h in zip(row, col, heights):                    # the reference: a loop over points
        want[r, c] = max(want[r, c], h) if want[r, c] != raster.nodata else h
    np.testing.assert_allclose(raster.z, want, atol=1e-9)
    assert raster.z[raster.valid].min() >= 0.0 and raster.z.max() > 20.0
    assert raster.count.sum() == len(xyz)


def test_the_chm_lies_on_the_dtms_lattice():
    xyz, cls = stand(1)
    cloud = Cloud.from_xyz(xyz, classification=cls)
    dtm = gfjax.dtm.build(cloud, cls == 2, cell_m=1.0)
    chm = gfjax.dtm.chm(cloud, cls == 2, cell_m=1.0)
    assert chm.origin == dtm.origin and chm.shape == dtm.shape and chm.transform == dtm.transform


def test_noise_is_left_out_and_empty_cells_are_nodata():
    xyz, cls = stand(2)
    noise = np.array([[700_010.0, 5_200_010.0, 900.0]])          # a bird 600 m up
    far = np.array([[700_045.0, 5_200_010.0, 303.0]])             # alone, 15 m east of the stand
    cloud = Cloud.from_xyz(np.concatenate([xyz, noise, far]), classification=np.concatenate([cls, [7, 5]]).astype(np.uint8))
    raster = gfjax.dtm.chm(cloud, cloud.classification == 2, cell_m=1.0)
    assert raster.z.max() < 30.0                                  # the bird is not canopy
    assert (~raster.valid).sum() > 0                              # the empty strip between


def test_bad_ground_is_named():
    xyz, cls = stand()
    cloud = Cloud.from_xyz(xyz, classification=cls)
    with pytest.raises(InputError, match=re.escape(f"{cloud.name}: no ground points")):
        gfjax.dtm.chm(cloud, np.zeros(len(xyz), bool))
    with pytest.raises(InputError, match=re.escape(f"{cloud.name}: ground must be a bool array")):
        gfjax.dtm.chm(cloud, cls)
