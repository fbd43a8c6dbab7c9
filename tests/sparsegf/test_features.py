"""SparseGF's input features: the top-hat heights against scipy.ndimage, the paper's xyz."""
from __future__ import annotations

import jax
import numpy as np
import pytest
from scipy import ndimage

from gfjax.sparsegf import features as F

HALF_M = 40.0


def reference_tophat(xyz, valid):
    """Heights over the cell minimum and its openings, from scipy.ndimage (float64)."""
    size = int(2 * HALF_M / F.TOPHAT_CELL_M)
    col = np.floor((xyz[:, 0] + HALF_M) / F.TOPHAT_CELL_M).astype(int)
    row = size - 1 - np.floor((xyz[:, 1] + HALF_M) / F.TOPHAT_CELL_M).astype(int)
    inside = valid & (col >= 0) & (col < size) & (row >= 0) & (row < size)
    zmin = np.full((size, size), np.inf)
    np.minimum.at(zmin, (row[inside], col[inside]), xyz[inside, 2])
    occupied = np.isfinite(zmin)
    out = np.zeros((len(xyz), 1 + len(F.TOPHAT_RADII_PX)))
    surfaces = [zmin]
    for r in F.TOPHAT_RADII_PX:
        eroded = ndimage.grey_erosion(zmin, size=2 * r + 1, mode="constant", cval=np.inf)
        surfaces.append(ndimage.grey_dilation(np.where(occupied, eroded, -np.inf), size=2 * r + 1,
                                              mode="constant", cval=-np.inf))
    for j, s in enumerate(surfaces):
        out[inside, j] = xyz[inside, 2] - s[row[inside], col[inside]]
    return out


def scene(seed, n=3000, slope=0.1):
    """Sloping ground with a building and a low outlier; some points outside the raster."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-45, 45, (n, 2))
    z = slope * xy[:, 0] + rng.normal(0, 0.05, n)
    roof = (np.abs(xy[:, 0] - 5) < 8) & (np.abs(xy[:, 1]) < 6)
    z = np.where(roof, z + 7.0, z)
    z[0] -= 20.0
    return np.column_stack([xy, z + 300.0]).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1])
def test_tophat_heights_equal_scipy_openings(seed):
    xyz = scene(seed)
    valid = np.random.default_rng(seed + 10).random(len(xyz)) < 0.9
    got = np.asarray(F.tophat_heights(xyz, valid, half_extent_m=HALF_M))
    np.testing.assert_allclose(got, reference_tophat(xyz.astype(np.float64), valid), atol=2e-4)
    assert np.all(got[~valid] == 0)
    assert np.all(got[valid] >= -1e-4)                  # an opening never rises above the points


def test_tophat_heights_see_a_roof_and_not_the_ground():
    xyz = scene(2, slope=0.0)
    h = np.asarray(F.tophat_heights(xyz, np.ones(len(xyz), bool), half_extent_m=HALF_M))
    roof = (np.abs(xyz[:, 0] - 5) < 6) & (np.abs(xyz[:, 1]) < 4)
    ground = ~roof & (np.abs(xyz[:, 0]) < 30)
    # windows of 33 and 65 m: wider than the roof (the 129 m one spans this 80 m raster, so the
    # low outlier's pit is the only surface it knows)
    for j in (-3, -2):
        assert np.median(h[roof, j]) > 6.5 and np.median(h[ground, j]) < 0.3
    assert np.median(h[roof, 1]) < 0.3      # a 3 m window sees the roof as ground


def test_tophat_under_vmap_equals_a_loop():
    batch = np.stack([scene(3, 500), scene(4, 500)])
    valid = np.ones(batch.shape[:2], bool)
    got = jax.vmap(lambda x, v: F.tophat_heights(x, v, half_extent_m=HALF_M))(batch, valid)
    for i in range(2):
        np.testing.assert_array_equal(np.asarray(got[i]), np.asarray(F.tophat_heights(batch[i], valid[i],
                                                                                      half_extent_m=HALF_M)))


def test_xyz_features_and_feature_counts():
    xyz = np.array([[44.0, -22.0, 5.0], [0.0, 0.0, -10.0]], np.float32)
    f = np.asarray(F.xyz_features(xyz, np.array([True, False]), r_oc_m=44.0))
    np.testing.assert_allclose(f[0], [1.0, -0.5, 0.5, 1.0])
    assert np.all(f[1] == 0)
    assert F.n_features("xyz") == 4 and F.n_features("xyz+tophat") == 4 + 1 + len(F.TOPHAT_RADII_PX)
    with pytest.raises(ValueError, match="features must be one of"):
        F.n_features("rgb")
