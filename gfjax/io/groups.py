"""Groups of points far apart, moved together: whole-cloud methods pay for points, not for the
empty box between them.

CSF, DMF and MASF build rasters over a cloud's bounding box. A cloud with a stray point 10 km
from the rest, or a few flight lines kilometres apart, would cost the memory and time of the
empty box. `compact` finds the groups of points separated by at least `gap_m` of emptiness
(the connected components of the occupied `gap_m` cells, 8-neighbourhood) and lays them side by
side, each still at least `gap_m` from the others, so a method that looks no further than
`gap_m` around a point sees each group as it would alone, over an area close to the groups'
own.

The layout keeps the largest group where it is (so its raster cells, anchored at the cloud's
minimum, are exactly those of a run without it) and shifts the others by whole `gap_m` cells
to its east. A cloud whose groups already fill its box (every ordinary tile) is left as it is:
`compact` returns None unless the layout shrinks the box by `MIN_SAVING` or more.

Host numpy and scipy (connected components); nothing here is traced.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from jaxtyping import Float, Int

GAP_M = 100.0        # emptiness that separates two groups, at least [m]
MIN_SAVING = 4.0     # compact only when the box shrinks at least this many times
_DENSE_CELLS = 1 << 22   # up to this many cells, occupancy is counted on a dense grid


class Layout(NamedTuple):
    """Where each group of a cloud goes.

    Attributes:
      group: `(n,)` int32, the group of each point (0 = the largest, which stays in place).
      shift_m: `(g, 2)` float64, the x, y shift of each group [m]; multiples of `gap_m`.
      gap_m: the separation the groups were found with [m].
    """

    group: Int[np.ndarray, " n"]
    shift_m: Float[np.ndarray, "g 2"]
    gap_m: float

    @property
    def n_groups(self) -> int:
        return len(self.shift_m)

    def apply(self, xyz_m: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
        """The points `(n, 3)` [m] with every group moved (a new float64 array)."""
        out = np.array(xyz_m, np.float64)
        out[:, :2] += self.shift_m[self.group]
        return out


def _occupied_cells(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """`(keys of the occupied cells (m,) sorted, cell row of each point (n,), rows of the key
    grid)` for cell indices `(n, 2)` >= 0. Keys are `(i + 1) * rows + j + 1`, so every
    neighbour of an occupied cell has a key of its own."""
    rows = int(cells[:, 1].max()) + 3
    key = (cells[:, 0] + 1) * rows + (cells[:, 1] + 1)
    n_keys = (int(cells[:, 0].max()) + 3) * rows
    if n_keys <= max(_DENSE_CELLS, 4 * len(cells)):
        hit = np.bincount(key, minlength=n_keys) > 0
        rank = np.cumsum(hit) - 1
        return np.flatnonzero(hit), rank[key].astype(np.int64), rows
    occupied, inverse = np.unique(key, return_inverse=True)
    return occupied, inverse.reshape(-1), rows


def separate(xy_m: Float[np.ndarray, "n 2"], gap_m: float) -> tuple[Int[np.ndarray, " n"], int]:
    """Groups of points: `(group of each point (n,) int32, number of groups)`.

    Two points share a group when a chain of occupied `gap_m` cells (8-neighbourhood) joins
    them; points of different groups are at least `gap_m` apart. Groups are numbered by
    decreasing point count.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    xy_m = np.asarray(xy_m, np.float64)
    if len(xy_m) == 0:
        return np.zeros(0, np.int32), 0
    cells = np.floor((xy_m - xy_m.min(axis=0)) / gap_m).astype(np.int64)
    occupied, point_cell, rows = _occupied_cells(cells)
    edges_from, edges_to = [], []
    for step in (1, rows - 1, rows, rows + 1):      # north, and the three cells to the east
        at = np.searchsorted(occupied, occupied + step)
        found = at < len(occupied)
        found[found] = occupied[at[found]] == occupied[found] + step
        edges_from.append(np.flatnonzero(found))
        edges_to.append(at[found])
    a, b = np.concatenate(edges_from), np.concatenate(edges_to)
    graph = coo_matrix((np.ones(len(a), np.int8), (a, b)), shape=(len(occupied), len(occupied)))
    n_groups, cell_group = connected_components(graph, directed=False)
    group = cell_group[point_cell]
    by_size = np.argsort(-np.bincount(group, minlength=n_groups), kind="stable")
    rename = np.empty(n_groups, np.int32)
    rename[by_size] = np.arange(n_groups, dtype=np.int32)
    return rename[group], int(n_groups)


def compact(xy_m: Float[np.ndarray, "n 2"], gap_m: float = GAP_M, *,
            min_saving: float = MIN_SAVING) -> Layout | None:
    """A layout that moves the groups of `xy_m` `(n, 2)` [m] together, or None when the cloud
    is one group or the layout would not shrink its bounding box `min_saving` times.

    Group 0 (the most points) stays in place. The others are packed in shelves (tallest first,
    in cells of `gap_m`) east of it and no lower than the cell row above its lowest one, with
    an empty cell between any two, so no moved point falls below or west of group 0's minimum
    and every group keeps `gap_m` of emptiness around it.
    """
    xy_m = np.asarray(xy_m, np.float64)
    if len(xy_m) == 0:
        return None
    lo = xy_m.min(axis=0)
    span_cells = np.floor((xy_m.max(axis=0) - lo) / gap_m) + 1
    if span_cells[0] * span_cells[1] < min_saving:
        return None                                  # the whole box is a few cells: nothing to win
    group, n_groups = separate(xy_m, gap_m)
    if n_groups == 1:
        return None
    cells = np.floor((xy_m - lo) / gap_m).astype(np.int64)
    first = np.full((n_groups, 2), np.iinfo(np.int64).max)
    last = np.full((n_groups, 2), -1, np.int64)
    np.minimum.at(first, group, cells)
    np.maximum.at(last, group, cells)
    size = last - first + 1                          # (g, 2) cells

    # shelves east of group 0: x from its last column + 2, y from its first row + 1
    x0, y0 = last[0, 0] + 2, first[0, 1] + 1
    others = np.arange(1, n_groups)
    order = others[np.argsort(-size[others, 1], kind="stable")]
    width = max(int(size[others, 0].max()) + 1, math.ceil(math.sqrt(float(np.prod(size[others] + 1, axis=1).sum()))))
    origin = first.copy()
    x = y = shelf = 0
    for g in order:
        w, h = int(size[g, 0]) + 1, int(size[g, 1]) + 1    # with the empty cell east and north
        if x > 0 and x + w > width:
            x, y, shelf = 0, y + shelf, 0
        origin[g] = (x0 + x, y0 + y)
        x += w
        shelf = max(shelf, h)
    new_last = origin + size - 1
    packed = (new_last.max(axis=0) - np.minimum(origin.min(axis=0), first[0]) + 1).astype(np.float64)
    if packed[0] * packed[1] * min_saving > span_cells[0] * span_cells[1]:
        return None
    return Layout(group=group, shift_m=(origin - first).astype(np.float64) * gap_m, gap_m=float(gap_m))


def compacted(xyz_m: Float[np.ndarray, "n 3"], gap_m: float = GAP_M) -> tuple[Float[np.ndarray, "n 3"], Layout | None]:
    """`(the points (n, 3) [m] with their far groups moved together, the layout)`, or
    `(xyz_m, None)` when `compact` finds nothing to win."""
    layout = compact(np.asarray(xyz_m)[:, :2], gap_m)
    return (xyz_m, None) if layout is None else (layout.apply(xyz_m), layout)
