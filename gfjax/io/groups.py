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

    @property
    def ij(self) -> np.ndarray:
        """`(m, 2)` int64 indices of the occupied cells."""
        return np.stack([self.keys // self.rows - 1, self.keys % self.rows - 1], axis=1)

    def point_cell(self) -> np.ndarray:
        """`(n,)` each point's row of `keys`."""
        if self.rank is not None:
            return self.rank[self.point_key]
        return np.searchsorted(self.keys, self.point_key)


def _cells(xy_m: np.ndarray, gap_m: float) -> _Cells:
    cells = np.floor((xy_m - xy_m.min(axis=0)) * (1.0 / gap_m)).astype(np.int64)
    span = cells.max(axis=0) + 1
    rows = int(span[1]) + 2
    key = cells[:, 0]
    key += 1
    key *= rows
    key += cells[:, 1] + 1
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
    which a tiled method filters group by group (`gfjax.io.tiled`)."""
    found = _far_groups(xy_m, gap_m, min_saving)
    if found is None:
        return None
    cells, cell_group, n_groups = found
    return cell_group[cells.point_cell()], n_groups


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


def compact(xy_m: Float[np.ndarray, "n 2"], gap_m: float = GAP_M, *,
            min_saving: float = MIN_SAVING) -> Layout | None:
    """A layout that moves the groups of `xy_m` `(n, 2)` [m] together, or None when the cloud
    is one group or the layout would not shrink its bounding box `min_saving` times.

    Group 0 (the most points) stays in place. The others are packed in shelves (tallest first,
    in cells of `gap_m`) east of it and no lower than the cell row above its lowest one, with
    an empty cell between any two, so no moved point falls below or west of group 0's minimum
    and every group keeps `gap_m` of emptiness around it.
    """
    found = _far_groups(xy_m, gap_m, min_saving)
    if found is None:
        return None
    cells, cell_group, n_groups = found
    box = float(cells.span[0]) * float(cells.span[1])
    first = np.full((n_groups, 2), np.iinfo(np.int64).max)
    last = np.full((n_groups, 2), -1, np.int64)
    ij = cells.ij
    np.minimum.at(first, cell_group, ij)
    np.maximum.at(last, cell_group, ij)
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
    if packed[0] * packed[1] * min_saving > box:
        return None
    group = cell_group[cells.point_cell()]
    return Layout(group=group, shift_m=(origin - first).astype(np.float64) * gap_m, gap_m=float(gap_m))


def compacted(xyz_m: Float[np.ndarray, "n 3"], gap_m: float = GAP_M, *,
              use: np.ndarray | None = None) -> tuple[Float[np.ndarray, "n 3"], Layout | None]:
    """`(the points (n, 3) [m] with the far groups of the used ones moved together, the
    layout)` (`use` `(n,)` bool: the points that count, default all; the others stay), or
    `(xyz_m, None)`, the same array, when `compact` finds nothing to win. The layout's
    `group` indexes the used points."""
    xyz_m = np.asarray(xyz_m)
    used = xyz_m if use is None else xyz_m[use]
    layout = compact(used[:, :2], gap_m)
    if layout is None:
        return xyz_m, None
    if use is None:
        return layout.apply(xyz_m), layout
    out = np.array(xyz_m, np.float64)
    out[use] = layout.apply(used)
    return out, layout
