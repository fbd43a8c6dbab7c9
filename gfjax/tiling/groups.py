"""Groups of points far apart: every method pays for points, not for the empty box between them.

The methods build rasters over a cloud's bounding box (CSF's cloth, DMF's NGNEM, MASF's grid)
or over its tiles (SMRF, PMF). A cloud with a stray point 10 km from the rest, a few flight
lines kilometres apart, or points spread thinly over a large area would cost the memory and
time of the empty box. `separate` finds the groups of points separated by at least `gap_m` of
emptiness (the connected components of the occupied `gap_m` cells, 8-neighbourhood), so a
method that looks no further than `gap_m` around a point can filter each group as a cloud of
its own (`driver.filter_groups`, `driver.classify_groups`). A cloud whose groups fill its
box (every ordinary tile: more than `1 / MIN_SAVING` of its `gap_m` cells occupied) is one
cloud (`far_apart`, `members` return None).

Host numpy and scipy (connected components); nothing here is traced.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

from gfjax.io import columns

GAP_M = 100.0        # emptiness that separates two groups, at least [m]
MIN_SAVING = 4.0     # split only a cloud whose occupied cells are at most 1 / this of its box
_DENSE_CELLS = 1 << 22   # up to this many cells, occupancy is counted on a dense grid


class _Cells(NamedTuple):
    """The occupied `gap_m` cells of some points: `span` `(2,)` cells of the points' box,
    `keys` `(m,)` the occupied cells' sorted keys, `point_key` `(n,)` each point's, `rank`
    (a dense box only) the row of each key in `keys`, and `rows` the key grid's rows
    (`key = (i + 1) * rows + j + 1`, so each neighbour has a key of its own)."""

    span: np.ndarray
    keys: np.ndarray
    point_key: np.ndarray
    rank: np.ndarray | None
    rows: int

    def point_cell(self) -> np.ndarray:
        """`(n,)` each point's row of `keys`."""
        if self.rank is not None:
            return self.rank[self.point_key]
        return np.searchsorted(self.keys, self.point_key)


def _cells(xy_m: np.ndarray, gap_m: float) -> _Cells:
    # column by column: numpy runs (n, 2) arithmetic through an inner loop of two elements
    low, scale = columns.lows(xy_m), 1.0 / gap_m
    i, j = (np.floor((xy_m[:, a] - low[a]) * scale).astype(np.int64) for a in range(2))
    span = np.array([i.max(), j.max()]) + 1
    rows = int(span[1]) + 2
    key = i
    key += 1
    key *= rows
    key += j + 1
    n_keys = (int(span[0]) + 2) * rows
    if n_keys <= max(_DENSE_CELLS, 4 * len(key)):            # O(n): a count per cell of the box
        hit = np.bincount(key, minlength=n_keys) > 0
        keys = np.flatnonzero(hit)
        rank = np.cumsum(hit) - 1
        return _Cells(span, keys, key, rank, rows)
    return _Cells(span, np.unique(key), key, None, rows)     # a sparse box: sort the keys


def _components(cells: _Cells) -> tuple[np.ndarray, int]:
    """`(group of each occupied cell (m,), number of groups)`, groups by decreasing point count."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    keys, m = cells.keys, len(cells.keys)
    edges_from, edges_to = [], []
    for step in (1, cells.rows - 1, cells.rows, cells.rows + 1):      # north, and the three cells to the east
        at = np.searchsorted(keys, keys + step)
        found = at < m
        found[found] = keys[at[found]] == keys[found] + step
        edges_from.append(np.flatnonzero(found))
        edges_to.append(at[found])
    a, b = np.concatenate(edges_from), np.concatenate(edges_to)
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(m, m))
    n_groups, cell_group = connected_components(graph, directed=False)
    points = np.bincount(cell_group[cells.point_cell()], minlength=n_groups)
    rename = np.empty(n_groups, np.int32)
    rename[np.argsort(-points, kind="stable")] = np.arange(n_groups, dtype=np.int32)
    return rename[cell_group], int(n_groups)


def separate(xy_m: Float[np.ndarray, "n 2"], gap_m: float) -> tuple[Int[np.ndarray, " n"], int]:
    """Groups of points: `(group of each point (n,) int32, number of groups)`.

    Two points share a group when a chain of occupied `gap_m` cells (8-neighbourhood) joins
    them; points of different groups are at least `gap_m` apart. Groups are numbered by
    decreasing point count.
    """
    xy_m = np.asarray(xy_m, np.float64)
    if len(xy_m) == 0:
        return np.zeros(0, np.int32), 0
    cells = _cells(xy_m, gap_m)
    cell_group, n_groups = _components(cells)
    return cell_group[cells.point_cell()], n_groups


def far_apart(xy_m: Float[np.ndarray, "n 2"], gap_m: float = GAP_M, *,
              min_saving: float = MIN_SAVING) -> tuple[Int[np.ndarray, " n"], int] | None:
    """The groups of `separate`, or None when the points fill their box (their occupied `gap_m`
    cells are more than `1 / min_saving` of it) or are one group: a cloud of groups far apart,
    which a tiled method filters group by group (`driver.classify_groups`)."""
    found = _far_groups(xy_m, gap_m, min_saving)
    if found is None:
        return None
    cells, cell_group, n_groups = found
    return cell_group[cells.point_cell()], n_groups


def members(xy_m: Float[np.ndarray, "n 2"], gap_m: float = GAP_M, *,
            index: Int[np.ndarray, " n"] | None = None) -> list[Int[np.ndarray, " k"]] | None:
    """The groups of `far_apart` as lists of points: `index` (default `arange(n)`) split into
    one int array per group, in group order, or None when `far_apart` finds no groups."""
    apart = far_apart(xy_m, gap_m)
    if apart is None:
        return None
    group, n_groups = apart
    index = np.arange(len(group)) if index is None else np.asarray(index)
    order = np.argsort(group, kind="stable")
    bounds = np.searchsorted(group[order], np.arange(n_groups + 1))
    return [index[order[bounds[g]:bounds[g + 1]]] for g in range(n_groups)]


def _far_groups(xy_m: np.ndarray, gap_m: float, min_saving: float) -> tuple[_Cells, np.ndarray, int] | None:
    """`(cells, group of each cell, number of groups)` of `far_apart`, or None."""
    xy_m = np.asarray(xy_m, np.float64)
    if len(xy_m) == 0:
        return None
    cells = _cells(xy_m, gap_m)
    if len(cells.keys) * min_saving > float(cells.span[0]) * float(cells.span[1]):
        return None                                  # the points fill their box: no layout is smaller
    cell_group, n_groups = _components(cells)
    return None if n_groups == 1 else (cells, cell_group, n_groups)
