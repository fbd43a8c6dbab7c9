"""The bucket-grid cylinder table (the speed path) against brute force and the KD-tree path."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from gfjax.dmf import neighbours


class Case(NamedTuple):
    name: str
    cell_m: float          # one node per cell of this side (the ND_CE layout)
    shape: tuple[int, int]
    radius_w: float
    jitter: str            # "uniform" in the cell, "quantised" to quarter cells, "corner" (integers)
    empty_share: float

    def __str__(self) -> str:
        return self.name


CASES = [Case("uniform", 1.0, (40, 30), 3.0, "uniform", 0.3),
         Case("quantised_ties", 1.0, (30, 30), 3.0, "quantised", 0.2),
         Case("cell_corners", 1.0, (20, 24), 3.0, "corner", 0.0),
         Case("w2_radius_2w", 2.0, (25, 20), 2.0, "uniform", 0.1),
         Case("one_row", 1.0, (1, 40), 3.0, "uniform", 0.0)]


def _nodes(case: Case, seed: int = 0) -> np.ndarray:
    """One node per non-empty cell, float64 `(m, 2)` [m], in raster order."""
    rng = np.random.default_rng(seed)
    h, w = case.shape
    rows, cols = np.nonzero(rng.uniform(size=(h, w)) >= case.empty_share)
    offset = {"uniform": rng.uniform(0, 1, (len(rows), 2)),
              "quantised": rng.integers(0, 4, (len(rows), 2)) / 4.0,
              "corner": np.zeros((len(rows), 2))}[case.jitter]
    return (np.stack([cols, h - 1 - rows], axis=1) + offset) * case.cell_m


def _brute_rows(xy: np.ndarray, radius_m: float) -> list[np.ndarray]:
    """Per node: the nodes within the radius (1e-9 relative slack, strict), by (d2, index)."""
    bound = radius_m * (1 + 1e-9)
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
    out = []
    for i in range(len(xy)):
        inside = np.flatnonzero(d2[i] < bound * bound)
        out.append(inside[np.lexsort((inside, d2[i, inside]))])
    return out


@pytest.mark.parametrize("case", CASES, ids=str)
def test_grid_table_matches_brute_force(case):
    xy = _nodes(case)
    radius_m = case.radius_w * case.cell_m
    table = neighbours.cylinder_table(xy, radius_m=radius_m, k=64, method="grid")
    expected = _brute_rows(xy, radius_m)
    assert not table.overflowed
    for i, row in enumerate(expected):
        np.testing.assert_array_equal(table.index[i][table.valid[i]], row)
        assert np.all(table.valid[i][:len(row)]) and np.all(table.index[i][~table.valid[i]] == i)


@pytest.mark.parametrize("case", CASES, ids=str)
@pytest.mark.parametrize("max_width", [8, None])
def test_grid_table_equals_kdtree_table(case, max_width):
    """Same neighbour sets, widths and overflow flags; same order up to equal distances."""
    xy = _nodes(case, seed=1)
    kwargs = dict(radius_m=case.radius_w * case.cell_m, k=(2 * int(np.ceil(case.radius_w)) + 1) ** 2,
                  max_width=max_width)
    grid = neighbours.cylinder_table(xy, method="grid", **kwargs)
    tree = neighbours.cylinder_table(xy, method="kdtree", **kwargs)
    assert grid.index.shape == tree.index.shape and grid.overflowed == tree.overflowed
    np.testing.assert_array_equal(grid.valid, tree.valid)
    d2 = lambda t: ((xy[t.index] - xy[:, None, :]) ** 2).sum(axis=2)     # noqa: E731
    np.testing.assert_array_equal(np.where(grid.valid, d2(grid), 0), np.where(tree.valid, d2(tree), 0))
    if max_width is None:
        np.testing.assert_array_equal(np.sort(np.where(grid.valid, grid.index, -1), axis=1),
                                      np.sort(np.where(tree.valid, tree.index, -1), axis=1))


def test_grid_table_overflow_keeps_the_nearest():
    xy = _nodes(CASES[0], seed=2)
    table = neighbours.cylinder_table(xy, radius_m=3.0, k=49, max_width=8, method="grid")
    assert table.overflowed and table.index.shape[1] == 8
    for i, row in enumerate(_brute_rows(xy, 3.0)):
        np.testing.assert_array_equal(table.index[i][table.valid[i]], row[:8])


def test_auto_falls_back_to_the_kdtree_when_a_bucket_holds_two_nodes():
    xy = np.random.default_rng(3).uniform(0, 30, (150, 2))
    with pytest.raises(ValueError, match="bucket"):
        neighbours.cylinder_table(xy, radius_m=4.0, k=64, method="grid")
    auto = neighbours.cylinder_table(xy, radius_m=4.0, k=64)
    tree = neighbours.cylinder_table(xy, radius_m=4.0, k=64, method="kdtree")
    np.testing.assert_array_equal(auto.index, tree.index)
    np.testing.assert_array_equal(auto.valid, tree.valid)


@pytest.mark.parametrize("m", [0, 1])
def test_grid_table_of_no_or_one_node(m):
    table = neighbours.cylinder_table(np.zeros((m, 2)), radius_m=3.0, k=49, method="grid")
    assert table.index.shape == (m, 8 if m else 49) and not table.overflowed
    assert table.valid.sum() == m


def test_cylinder_table_rejects_unknown_method():
    with pytest.raises(ValueError, match="method"):
        neighbours.cylinder_table(np.zeros((3, 2)), radius_m=1.0, k=8, method="octree")
