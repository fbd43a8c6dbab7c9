"""Cylindrical partition: membership against brute force, capacity buckets, and coverage of
every point by the central regions as `compress` computes them (float32, patch frame)."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.errors import InputError
from gfjax.sparsegf import (
    CENTRAL_TOL_M,
    R_IN_M,
    R_OO_M,
    STEP_M,
    PartitionConfig,
    compress,
    partition,
    soft_vote,
)
from gfjax.sparsegf.partition import cylinders, grid_centers
from gfjax.tiling.buckets import capacity_bucket

UTM = np.array([512_345.678, 5_403_210.987, 0.0])   # far from the origin: float64 input


def grid_corner_cloud():
    """A 100 m x 100 m box: points on its corners, edges and at the 4-way grid corner (50, 50),
    which is exactly R_in from four patch axes and central only thanks to the tolerance."""
    rng = np.random.default_rng(0)
    edge = np.array([[0, 0], [100, 0], [0, 100], [100, 100], [50, 50], [50, 0], [0, 50], [100, 50],
                     [50, 100], [25, 0], [0, 75], [100, 33.3], [49.999, 50.001]], dtype=np.float64)
    inner = rng.uniform(0, 100, (300, 2))
    xy = np.concatenate([edge, inner])
    return np.concatenate([xy, rng.uniform(0, 30, (len(xy), 1))], axis=1) + UTM


def l_shaped_cloud():
    """An irregular footprint with empty grid cells (no patch is kept there)."""
    rng = np.random.default_rng(1)
    a = rng.uniform([0, 0], [420, 60], (3000, 2))
    b = rng.uniform([0, 0], [60, 380], (2000, 2))
    xy = np.concatenate([a, b])
    return np.concatenate([xy, rng.uniform(100, 140, (len(xy), 1))], axis=1)


CLOUDS = {
    "grid_corners_utm": grid_corner_cloud,
    "l_shape": l_shaped_cloud,
    "smaller_than_a_cell": lambda: np.random.default_rng(2).uniform([5, 5, 0], [15, 12, 3], (50, 3)) + UTM,
    "single_point": lambda: np.array([[3.0, 4.0, 5.0]]),
    "line_along_x": lambda: np.stack([np.linspace(0, 333, 400), np.full(400, 7.0), np.zeros(400)], axis=1),
}


@pytest.fixture(scope="module")
def compress_batch():
    """One jitted vmapped compress in the patch frame (axis at the origin)."""
    def one(p, v):
        return compress(p, jnp.zeros(2, jnp.float32), valid=v).central
    return jax.jit(jax.vmap(one))


def brute_force_members(xy, center, radius):
    d = xy - center
    return np.flatnonzero(np.einsum("ij,ij->i", d, d) <= radius ** 2)


@pytest.mark.parametrize("name", CLOUDS, ids=str)
def test_membership_matches_brute_force(name):
    xyz = CLOUDS[name]()
    part = partition(xyz)
    seen = set()
    for batch in part.batches:
        assert batch.capacity == capacity_bucket(batch.capacity)
        np.testing.assert_array_equal(batch.valid, batch.index >= 0)
        for row, pid in enumerate(batch.patch_id):
            seen.add(int(pid))
            np.testing.assert_array_equal(batch.center_m[row], part.centers_m[pid])
            members = batch.index[row][batch.valid[row]]
            assert np.all(batch.valid[row][:len(members)]), "padding must come last"
            np.testing.assert_array_equal(np.sort(members), brute_force_members(xyz[:, :2], part.centers_m[pid], R_OO_M))
            assert len(members) == part.n_points[pid]
            assert capacity_bucket(len(members)) == batch.capacity
    assert seen == set(range(len(part.centers_m)))


@pytest.mark.parametrize("name", CLOUDS, ids=str)
def test_central_regions_cover_every_point(name, compress_batch):
    xyz = CLOUDS[name]()
    part = partition(xyz)
    count = np.zeros(len(xyz), np.int64)
    for batch in part.batches:
        central = compress_batch(jnp.asarray(batch.local_xyz(xyz)), jnp.asarray(batch.valid))
        vote = soft_vote(jnp.asarray(batch.index), jnp.ones(batch.index.shape, jnp.float32), len(xyz),
                         mask=central)
        count += np.asarray(vote.count)
    assert count.min() >= 1, f"{np.sum(count == 0)} points in no central region"
    # the same count in float64 from the kept axes
    d = xyz[:, None, :2] - part.centers_m[None, :, :]
    expected = np.sum(np.hypot(d[..., 0], d[..., 1]) <= R_IN_M + CENTRAL_TOL_M, axis=1)
    np.testing.assert_array_equal(count, expected)
    # every kept patch classifies something, and no axis has more than 4 neighbours' overlap
    assert count.max() <= 4


def test_grid_corner_point_is_central_in_four_patches(compress_batch):
    xyz = grid_corner_cloud()
    part = partition(xyz)
    np.testing.assert_allclose(np.sort(part.centers_m[:, 0] - UTM[0]), [25, 25, 75, 75])
    corner = 4                                              # (50, 50)
    hits = 0
    for batch in part.batches:
        central = np.asarray(compress_batch(jnp.asarray(batch.local_xyz(xyz)), jnp.asarray(batch.valid)))
        hits += int(np.sum(central & (batch.index == corner)))
    assert hits == 4


def test_small_cloud_is_one_patch_with_every_point_central():
    xyz = CLOUDS["smaller_than_a_cell"]()
    part = partition(xyz)
    assert len(part.centers_m) == 1 and len(part.batches) == 1
    np.testing.assert_allclose(part.centers_m[0], (xyz[:, :2].min(0) + xyz[:, :2].max(0)) / 2)
    np.testing.assert_array_equal(part.batches[0].index[0, :len(xyz)], np.arange(len(xyz)))


def test_empty_cells_are_dropped():
    xyz = l_shaped_cloud()
    part = partition(xyz)
    nx, ny = int(np.ceil(420 / STEP_M)), int(np.ceil(380 / STEP_M))
    assert len(part.centers_m) < nx * ny
    d = xyz[None, :, :2] - part.centers_m[:, None, :]
    assert np.all(np.any(np.hypot(d[..., 0], d[..., 1]) <= R_IN_M, axis=1))


def test_a_sparse_cloud_over_a_large_box_keeps_exactly_the_cells_near_its_points():
    # 150 points over 6 km x 6 km (14,400 grid cells), two of them 1 m apart: the kept axes
    # are every cell centre within R_in of a point, found by brute force over the whole grid
    rng = np.random.default_rng(7)
    xy = rng.uniform(0, 6_000, (150, 2))
    xy[1] = xy[0] + 1.0
    xy = xy + UTM[:2]
    part = partition(np.column_stack([xy, np.zeros(len(xy))]))
    centres, (ny, nx), _ = grid_centers(xy.min(axis=0), xy.max(axis=0), STEP_M)
    assert nx * ny > 14_000
    near = np.hypot(*(centres[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) <= R_IN_M + CENTRAL_TOL_M
    want = centres[near.any(axis=1)]
    order = np.lexsort((part.centers_m[:, 0], part.centers_m[:, 1]))
    np.testing.assert_allclose(part.centers_m[order], want[np.lexsort((want[:, 0], want[:, 1]))], atol=1e-6)


def _patches_by_cell(part, point_index):
    """`{cell: (centre, members as indices of the whole cloud)}` of a partition."""
    out = {}
    for batch in part.batches:
        for row, pid in enumerate(batch.patch_id):
            members = batch.index[row][batch.valid[row]]
            out[int(part.cells[pid])] = (part.centers_m[pid], np.sort(point_index[members]))
    return out


@pytest.mark.parametrize("window", [(0, 0, 230, 170), (0, 0, 420, 250), (-50, 100, 80, 500)], ids=str)
def test_a_window_laid_on_the_frame_shares_the_whole_clouds_patches(window):
    # the window's patches are cells of the frame's grid: those whose cylinder's points the
    # window holds all of are the whole cloud's patches of the same cells, point for point
    xyz = l_shaped_cloud() + UTM
    box = (xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0))
    whole = _patches_by_cell(partition(xyz, box=box), np.arange(len(xyz)))
    lo, hi = np.asarray(window[:2], float) + UTM[:2], np.asarray(window[2:], float) + UTM[:2]
    inside = np.flatnonzero(np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1))
    part = partition(xyz[inside], box=box)
    held = 0
    for cell, (centre, members) in _patches_by_cell(part, inside).items():
        assert cell in whole
        np.testing.assert_array_equal(centre, whole[cell][0])
        if np.isin(whole[cell][1], inside).all():
            np.testing.assert_array_equal(members, whole[cell][1])
            held += 1
    assert held


def test_a_grid_laid_on_a_box_names_its_cells_on_that_box():
    # a cloud of 30 points at one end of a 200 km box: the cells are the box's, and the
    # partition makes only those near the points
    xy = np.random.default_rng(3).uniform(0, 80, (30, 2)) + [199_900.0, 10.0]
    box = (np.zeros(2), np.array([200_000.0, 400.0]))
    part = partition(np.column_stack([xy, np.zeros(30)]), box=box)
    centres, (ny, nx), _ = grid_centers(*box, STEP_M)
    np.testing.assert_allclose(part.centers_m, centres[part.cells])
    near = np.hypot(*(centres[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) <= R_IN_M + CENTRAL_TOL_M
    assert set(part.cells.tolist()) == set(np.flatnonzero(near.any(axis=1)).tolist())


def test_without_a_box_the_cells_are_those_of_the_points_own_grid():
    xyz = l_shaped_cloud()
    own = partition(xyz)
    laid = partition(xyz, box=(xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)))
    np.testing.assert_array_equal(own.cells, laid.cells)
    np.testing.assert_array_equal(own.centers_m, laid.centers_m)


def test_local_xyz_is_relative_to_the_axis():
    xyz = grid_corner_cloud()
    batch = partition(xyz).batches[0]
    local = batch.local_xyz(xyz)
    assert local.dtype == np.float32 and local.shape == batch.index.shape + (3,)
    v = batch.valid
    expected = xyz[batch.index[v]] - np.concatenate([np.repeat(batch.center_m, v.sum(1), axis=0),
                                                     np.zeros((v.sum(), 1))], axis=1)
    np.testing.assert_allclose(local[v], expected, rtol=0, atol=1e-4)
    assert np.all(local[~v] == 0)


def test_empty_cloud_has_no_patches():
    part = partition(np.zeros((0, 3)))
    assert part.batches == () and part.centers_m.shape == (0, 2)


@pytest.mark.parametrize("bad, match", [(np.zeros((4, 4)), "shape"),
                                        (np.array([[0.0, np.nan, 1.0]]), "non-finite")])
def test_bad_input_raises(bad, match):
    with pytest.raises(InputError, match=match):
        partition(bad)


def test_config_that_leaves_gaps_raises():
    with pytest.raises(InputError, match="gaps"):
        PartitionConfig(step_m=60.0)
    with pytest.raises(InputError, match="step_m"):
        PartitionConfig(step_m=0.0)


@pytest.mark.parametrize("reach_m", [0.0, 20.0, 60.0])
def test_a_core_keeps_exactly_the_patches_that_vote_near_it(reach_m):
    # a core in the L's corner: the kept axes are those within r_in + reach of a core point
    # (brute force), each patch has the members the whole partition gives its cell, and every
    # point within the reach of the core is central in all the patches that vote on it in the
    # whole cloud
    xyz = l_shaped_cloud() + UTM
    core = np.all(xyz[:, :2] - UTM[:2] < [90.0, 70.0], axis=1)
    whole = partition(xyz)
    found = cylinders(xyz, core=core, core_reach_m=reach_m)
    d = np.hypot(*(whole.centers_m[:, None, :] - xyz[None, core, :2]).transpose(2, 0, 1))
    want = np.flatnonzero((d <= R_IN_M + CENTRAL_TOL_M + reach_m).any(axis=1))
    np.testing.assert_array_equal(found.cells, whole.cells[want])
    np.testing.assert_array_equal(found.centers_m, whole.centers_m[want])
    assert 0 < len(found) < len(whole.centers_m)
    members = {int(pid): batch.index[row][batch.valid[row]]
               for batch in whole.batches for row, pid in enumerate(batch.patch_id)}
    for p, pid in enumerate(want):
        np.testing.assert_array_equal(found.members(p), members[int(pid)])
    near = np.hypot(*(xyz[:, None, :2] - xyz[None, core, :2]).transpose(2, 0, 1)).min(axis=1) <= reach_m
    central = np.hypot(*(xyz[:, None, :2] - whole.centers_m[None]).transpose(2, 0, 1)) <= R_IN_M + CENTRAL_TOL_M
    assert np.all(central[near][:, np.setdiff1d(np.arange(len(whole.centers_m)), want)] == 0)


def test_no_core_point_no_patch():
    xyz = l_shaped_cloud()
    assert len(cylinders(xyz, core=np.zeros(len(xyz), bool))) == 0
    with pytest.raises(InputError, match="core must have shape"):
        cylinders(xyz, core=np.ones(3, bool))
