"""DMF host steps: voxel size (Eq. 1), voxel columns / ND_CE, cylinder tables (scipy-free references)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from gfjax.dmf import neighbours, voxels


def _cloud(seed: int, n: int = 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, 20, n), rng.uniform(0, 15, n), rng.uniform(0, 6, n)])


@pytest.mark.parametrize("seed", [0, 1])
def test_voxel_size_matches_brute_force(seed):
    xyz = _cloud(seed)
    w_m, mean_m = voxels.voxel_size_m(xyz, v0=2.0, fraction=0.01, minimum=100)
    sample = voxels.nn_sample(len(xyz), xyz, fraction=0.01, minimum=100)
    d = np.linalg.norm(xyz[sample][:, None, :] - xyz[None, :, :], axis=2)
    d[np.arange(len(sample)), sample] = np.inf
    expected = d.min(axis=1).mean()
    assert len(sample) == 100
    np.testing.assert_allclose(mean_m, expected, rtol=1e-12)
    assert w_m == max(1, math.ceil(2.0 * expected))


def test_voxel_size_is_point_order_invariant():
    xyz = _cloud(3, 2000)
    perm = np.random.default_rng(0).permutation(len(xyz))
    a = voxels.voxel_size_m(xyz, v0=2.0, fraction=0.01, minimum=100)
    b = voxels.voxel_size_m(xyz[perm], v0=2.0, fraction=0.01, minimum=100)
    assert a == b


def test_voxel_size_of_duplicates_is_one_metre():
    xyz = np.zeros((50, 3))
    assert voxels.voxel_size_m(xyz, v0=2.0, fraction=0.01, minimum=10) == (1.0, 0.0)


@pytest.mark.parametrize("stacked", [3000, 300])
def test_nn_distances_of_a_stacked_cloud_match_brute_force(stacked):
    """Most points on a few places (a k-d tree cannot split them) or a few stacks among many
    points: the distances are the brute force's either way (a point with a twin: 0)."""
    rng = np.random.default_rng(5)
    spread = _cloud(6, 600)
    xyz = np.vstack([np.repeat(spread[:3], stacked // 3, axis=0), spread[3:]])
    xyz = xyz[rng.permutation(len(xyz))]
    sample = voxels.nn_sample(len(xyz), xyz, fraction=0.5, minimum=300)
    got = voxels.nn_distances(xyz, fraction=0.5, minimum=300, sample=sample)
    d = np.linalg.norm(xyz[sample][:, None, :] - xyz[None, :, :], axis=2)
    d[np.arange(len(sample)), sample] = np.inf
    np.testing.assert_allclose(got, d.min(axis=1), rtol=1e-12)


def test_bin_voxels_matches_loop():
    xyz = _cloud(4)
    cell_m = 2.0
    vox = voxels.bin_voxels(xyz, cell_m)
    h, w = vox.shape
    ijk = np.floor(xyz / cell_m).astype(int)
    assert (w, h) == (ijk[:, 0].max() + 1, ijk[:, 1].max() + 1)
    expected = {}
    for (i, j, k), p in zip(ijk, xyz):
        key = (h - 1 - j) * w + i
        if key not in expected or k < expected[key][0]:
            expected[key] = (k, [p])
        elif k == expected[key][0]:
            expected[key][1].append(p)
    assert list(vox.cell) == sorted(expected)
    for node, cell in enumerate(vox.cell):
        k, pts = expected[cell]
        assert vox.layer[node] == k
        np.testing.assert_allclose(vox.centroid[node], np.mean(pts, axis=0), rtol=1e-12)
        assert vox.node_of_cell[cell] == node
    np.testing.assert_array_equal(vox.point_cell, (h - 1 - ijk[:, 1]) * w + ijk[:, 0])
    assert (vox.node_of_cell >= 0).sum() == len(vox.cell)


def test_cylinder_table_matches_brute_force():
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 30, (150, 2))
    table = neighbours.cylinder_table(xy, radius_m=4.0, k=200)
    width = table.index.shape[1]
    assert width & (width - 1) == 0 and width >= 8 and not table.overflowed
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    for i in range(len(xy)):
        assert set(table.index[i][table.valid[i]]) == set(np.flatnonzero(d[i] <= 4.0))
        assert np.all(table.index[i][~table.valid[i]] == i)


def test_cylinder_table_reports_overflow():
    xy = np.zeros((20, 2))
    table = neighbours.cylinder_table(xy, radius_m=1.0, k=8, shrink=False)
    assert table.overflowed and table.index.shape == (20, 8)


def test_cylinder_table_width_cap_keeps_the_nearest():
    rng = np.random.default_rng(6)
    xy = rng.uniform(0, 10, (300, 2))
    full = neighbours.cylinder_table(xy, radius_m=3.0, k=300)
    capped = neighbours.cylinder_table(xy, radius_m=3.0, k=300, max_width=8)
    assert capped.index.shape == (300, 8) and capped.overflowed
    np.testing.assert_array_equal(capped.index, full.index[:, :8])
