"""Groups of points far apart: found as scipy.ndimage labels the occupied cells, and laid out
so that each keeps its emptiness around it and the largest stays where it is."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from gfjax.io import groups


def _clusters(rng, centres, per=50, spread=20.0):
    return np.vstack([c + rng.uniform(0, spread, (per, 2)) for c in centres])


def _reference_groups(xy, gap):
    cells = np.floor((xy - xy.min(axis=0)) / gap).astype(int)
    grid = np.zeros(cells.max(axis=0) + 1, bool)
    grid[cells[:, 0], cells[:, 1]] = True
    labels, n = ndimage.label(grid, structure=np.ones((3, 3)))
    return labels[cells[:, 0], cells[:, 1]], n


def _same_partition(a, b):
    pairs = set(zip(a.tolist(), b.tolist()))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


@pytest.mark.parametrize("seed", range(6))
def test_groups_are_the_8_connected_components_of_occupied_cells(seed):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 3000, (rng.integers(1, 400), 2)) * rng.uniform(0.2, 1.0, 2)
    group, n = groups.separate(xy, 100.0)
    want, n_want = _reference_groups(xy, 100.0)
    assert n == n_want and _same_partition(group, want)
    counts = np.bincount(group)
    assert np.all(np.diff(counts) <= 0)                  # numbered by decreasing size


def test_groups_on_a_sparse_box_take_the_unique_path():
    """A box of more cells than the dense grid allows (1e4 km across) is read with np.unique."""
    rng = np.random.default_rng(1)
    xy = np.vstack([rng.uniform(0, 50, (200, 2)), [[1e7, 1e7], [1e7 + 30, 1e7]]])
    group, n = groups.separate(xy, 100.0)
    assert n == 2 and np.all(group[:200] == 0) and np.all(group[200:] == 1)


def test_points_on_diagonal_cells_join_and_a_one_cell_gap_separates():
    xy = np.array([[5.0, 5.0], [105.0, 105.0], [305.0, 105.0]])   # (0,0)-(1,1) touch; (3,1) does not
    group, n = groups.separate(xy, 100.0)
    assert n == 2 and group[0] == group[1] != group[2]


def test_separate_of_no_point():
    group, n = groups.separate(np.zeros((0, 2)), 100.0)
    assert n == 0 and group.shape == (0,)


@pytest.mark.parametrize("seed", range(5))
def test_layout_keeps_every_group_a_gap_from_the_others_and_the_largest_in_place(seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 20_000, (12, 2))
    xy = np.vstack([_clusters(rng, centres[:1], per=400, spread=300.0), _clusters(rng, centres[1:])])
    layout = groups.compact(xy, 100.0)
    assert layout is not None
    moved = layout.apply(np.column_stack([xy, rng.normal(size=len(xy))]))
    assert np.all(layout.shift_m[0] == 0) and np.all(moved[layout.group == 0, :2] == xy[layout.group == 0])
    assert np.all(np.mod(layout.shift_m, 100.0) == 0)
    assert np.allclose(moved.min(axis=0)[:2], xy[layout.group == 0].min(axis=0))    # the raster anchor
    for g in range(1, layout.n_groups):
        inside, outside = moved[layout.group == g, :2], moved[layout.group != g, :2]
        nearest = np.min(np.linalg.norm(inside[:, None] - outside[None], axis=-1))
        assert nearest >= 100.0
    area = np.prod(np.ptp(moved[:, :2], axis=0))
    assert area * groups.MIN_SAVING <= np.prod(np.ptp(xy, axis=0) + 100.0)
    assert np.array_equal(moved[:, 2], layout.apply(moved)[:, 2])                   # z never moves


def test_a_cloud_that_fills_its_box_is_left_alone():
    rng = np.random.default_rng(0)
    full = rng.uniform(0, 1000, (5000, 2))
    assert groups.compact(full, 100.0) is None
    lake = full[np.linalg.norm(full - 500, axis=1) > 300]        # one group round a lake
    assert groups.compact(lake, 100.0) is None
    two = np.vstack([full, full + [1200.0, 0.0]])                # two groups, little to win
    assert groups.compact(two, 100.0) is None
    xyz = np.column_stack([full, np.ones(len(full))])
    same, layout = groups.compacted(xyz)
    assert layout is None and same is xyz
