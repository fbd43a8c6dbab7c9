"""Groups of points far apart: found as scipy.ndimage labels the occupied cells, and split
only where they leave most of their box empty."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from gfjax.tiling import groups


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
def test_members_of_groups_far_apart_hold_every_point_once_and_keep_the_gap(seed):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 20_000, (12, 2))
    xy = np.vstack([_clusters(rng, centres[:1], per=400, spread=300.0), _clusters(rng, centres[1:])])
    index = rng.permutation(len(xy)) + 7                         # members are given in these names
    found = groups.members(xy, 100.0, index=index)
    assert found is not None
    assert np.array_equal(np.sort(np.concatenate(found)), np.sort(index))
    assert [len(m) for m in found] == sorted((len(m) for m in found), reverse=True)
    position = {name: k for k, name in enumerate(index)}
    for names in found:
        inside = xy[[position[n] for n in names]]
        outside = np.delete(xy, [position[n] for n in names], axis=0)
        assert np.min(np.linalg.norm(inside[:, None] - outside[None], axis=-1)) >= 100.0


def test_a_cloud_that_fills_its_box_is_one_cloud():
    rng = np.random.default_rng(0)
    full = rng.uniform(0, 1000, (5000, 2))
    assert groups.members(full, 100.0) is None
    lake = full[np.linalg.norm(full - 500, axis=1) > 300]        # one group round a lake
    assert groups.members(lake, 100.0) is None
    two = np.vstack([full, full + [1200.0, 0.0]])                # two groups filling their box
    assert groups.members(two, 100.0) is None
    assert groups.members(np.zeros((0, 2)), 100.0) is None
