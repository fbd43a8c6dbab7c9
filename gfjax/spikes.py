"""A guard against ground spikes: ground points far above or below the ground around them, and
ground points stacked over other returns.

A filter that keeps a chimney top, a wire or a multipath return far below the terrain as ground
puts a spike in the DTM: one cell metres off, which a surveyor sees at once and a flood model
follows. Such a point stands alone among the ground points around it, so it is told by them:
with its `k` nearest ground neighbours (in x, y), a point whose height differs from their
median by more than `threshold_m + slope * d` (`d`: the median distance to them, so a slope of
`slope` between them and the point is tolerated) is no ground. Larger wrongly kept objects
(a whole roof) are a filter's own business: this only removes what no ground surface can hold.

The terrain is one height per place, so a return well below a ground point beside it says the
point is not on the terrain: a bridge deck over its valley, a roof edge over the street. `unstack`
drops ground points with a used return more than `drop_m` below them in the 3 x 3 cells around
them; `drop_m` grows with the terrain's slope (`stacked_drop_m`), so a steep slope's own fall
across those cells is no drop.

Host code (scipy's cKDTree), run once on a method's labels; `despike` is pure: labels in, labels
out.
"""
from __future__ import annotations

import math

import numpy as np

from gfjax.io import columns

__all__ = ["guard", "despike", "unstack", "stacked_drop_m", "NEIGHBOURS", "THRESHOLD_M", "SLOPE", "MIN_DROP_M",
           "DROP_SLOPES", "MIN_CELL_M"]

# Chosen on the training files with the labels of SMRF, DMF and MASF (the most files passing
# over the three; ties: the lowest ISPRS total error of SMRF): 8 neighbours, 1 m, slope 0.5.
PROBE = 256             # ground points looked at first for stacks of coincident points
QUERY_ROWS = 1 << 16     # ground points whose neighbours are found at a time (memory, not labels)
SURE_CELL_SPACINGS = 3.0   # the cell of `_unsure`, in point spacings (speed, not labels)
NEIGHBOURS = 8           # ground neighbours a point is compared with
THRESHOLD_M = 1.0        # height off their median tolerated next to them [m]
SLOPE = 0.5              # ... plus this rise over run, over the median distance to them

# Chosen on the training files with SMRF's labels (fixes samp21's viaduct, the fewest ground points
# lost on the steep ISPRS samples): a return 5 m below, or more than 10 cells of the terrain's
# 90th-percentile slope below (about 3x that slope over the 3 cells a neighbourhood spans).
MIN_DROP_M = 5.0         # a return this far below a ground point beside it unmakes the point [m]
DROP_SLOPES = 10.0       # ... or, on steep terrain, this many cells of the 90th-percentile slope
MIN_CELL_M = 1.0         # the neighbourhood's cell: the point spacing, at least this [m]


def _median_rows(a: np.ndarray) -> np.ndarray:
    """`np.median(a, axis=1)` of a float `(m, k)` array, by one partition (no sort)."""
    k = a.shape[1]
    middle = [(k - 1) // 2, k // 2]
    part = np.partition(a, middle, axis=1)
    return 0.5 * (part[:, middle[0]] + part[:, middle[1]])


def _median_sorted_rows(a: np.ndarray) -> np.ndarray:
    """`_median_rows` of rows already in ascending order (a KD-tree's distances): no partition."""
    k = a.shape[1]
    return 0.5 * (a[:, (k - 1) // 2] + a[:, k // 2])


def _tree(xy: np.ndarray):
    """scipy's cKDTree over points `xy` `(n, 2)`, split at sliding midpoints rather than medians:
    it finds the same exact nearest neighbours and builds faster (the guard over every labelled
    file took 3.24 s against 3.97 s). Neighbours at equal distance may come in another order; no
    label of any labelled file changed (SMRF's and the reference ground; both:
    `experiments/spike_guard.py`)."""
    from scipy.spatial import cKDTree

    return cKDTree(xy, balanced_tree=False)


def despike(xyz_m: np.ndarray, ground: np.ndarray, *, threshold_m: float = THRESHOLD_M, slope: float = SLOPE,
            k: int = NEIGHBOURS) -> np.ndarray:
    """Ground labels without the spikes (see the module docstring).

    Args:
      xyz_m: coordinates, float `(n, 3)` [m].
      ground: bool `(n,)`, a filter's labels.
      threshold_m: height off the neighbours' median tolerated next to them [m].
      slope: rise over run tolerated on top, over the median distance to them [-].
      k: neighbours compared with.

    Returns:
      bool `(n,)`: `ground` with the spikes False. With `k` or fewer ground points, `ground`.
    """
    ground = np.asarray(ground, dtype=bool)
    index = np.flatnonzero(ground)
    if index.size <= k:
        return ground.copy()
    # column by column: numpy runs (n, 2) and (n, 3) arithmetic through an inner loop of 2 or 3
    xyz = np.asarray(xyz_m, dtype=np.float64)
    xy = np.empty((index.size, 2))
    for j in range(2):                    # one gathered column alive at a time
        column = xyz[:, j][index]
        np.subtract(column, column.min(), out=xy[:, j])
        del column
    z = xyz[:, 2][index]
    tree = _tree(xy)
    # A place held by more than k points (a stack of coincident returns) would make every query
    # near it scan the whole stack. A probe tells whether the cloud has one worth the care.
    probe = np.linspace(0, len(xy) - 1, min(PROBE, len(xy))).astype(np.int64)
    if np.any(tree.query(xy[probe], k=k + 1, workers=-1)[0][:, k] == 0.0):
        return _despike_stacked(z, xy, index, ground, threshold_m=threshold_m, slope=slope, k=k)
    out = ground.copy()
    unsure = _unsure(xy, z, threshold_m=threshold_m, slope=slope, k=k)
    for start in range(0, unsure.size, QUERY_ROWS):   # a slice at a time: k neighbours a point is 150 bytes
        rows = unsure[start:start + QUERY_ROWS]
        distance, neighbour = tree.query(xy[rows], k=k + 1, workers=-1)
        distance, neighbour = distance[:, 1:], neighbour[:, 1:]          # the point itself first
        off = z[rows] - _median_rows(z[neighbour])
        allowed = threshold_m + slope * _median_sorted_rows(distance)  # distances come sorted
        out[index[rows][np.abs(off) > allowed]] = False
    return out


def _unsure(xy: np.ndarray, z: np.ndarray, *, threshold_m: float, slope: float, k: int) -> np.ndarray:
    """The rows, int64 `(m,)` ascending, of the ground points `xy` `(n, 2)` [m from their
    corner], `z` `(n,)` [m] that `despike` must compare with their neighbours: all but those
    that no median of their neighbours can make a spike.

    On square cells of `SURE_CELL_SPACINGS` point spacings, a point whose own cell holds more
    than `k` points has its `k` nearest within a cell's diagonal, so inside the 5 x 5 cells
    around it; when every height there lies within `threshold_m` of its own, so does their
    median, and the tolerance of `despike` (`threshold_m` plus a rise of `slope` >= 0) holds it,
    exactly, in floating point too (each step rounds monotonically). Such points are no query:
    most ground points of a dense, gentle cloud (the cells' extremes cost one pass). Every point
    is queried under a negative slope or threshold, and for points on a line or a strip so
    thin that its cells would outnumber them four times."""
    span = xy.max(axis=0)
    area = float(span[0]) * float(span[1])
    if slope < 0 or not threshold_m >= 0 or not area > 0:
        return np.arange(len(xy))
    cell_m = SURE_CELL_SPACINGS * np.sqrt(area / len(xy))
    shape = (int(span[1] // cell_m) + 1, int(span[0] // cell_m) + 1)
    if shape[0] * shape[1] > 4 * len(xy):
        return np.arange(len(xy))
    key = (xy[:, 1] // cell_m).astype(np.int64)
    key *= shape[1]
    key += (xy[:, 0] // cell_m).astype(np.int64)
    count = np.bincount(key, minlength=shape[0] * shape[1])
    low, high = np.full(count.size, np.inf), np.full(count.size, -np.inf)
    np.minimum.at(low, key, z)
    np.maximum.at(high, key, z)
    # a grid of about n / 9 cells: numpy's windowed view, not scipy.ndimage's import (0.07 s)
    low = _around(low.reshape(shape), np.inf, np.min)
    high = _around(high.reshape(shape), -np.inf, np.max)
    sure = count[key] > k
    sure &= z - low[key] <= threshold_m
    sure &= high[key] - z <= threshold_m
    return np.flatnonzero(~sure)


def _around(grid: np.ndarray, empty: float, fold, size: int = 5) -> np.ndarray:
    """`fold` (`np.min`, `np.max`) of the `size` x `size` cells (odd) around each cell of
    `grid` `(h, w)`, `empty` beyond its edges: flat `(h * w,)`."""
    window = np.lib.stride_tricks.sliding_window_view
    reach = size // 2
    rows = fold(window(np.pad(grid, reach, constant_values=empty), size, axis=1), axis=2)   # (h + 2 reach, w)
    return fold(window(rows, size, axis=0), axis=2).reshape(-1)


def _despike_stacked(z, xy, index, ground, *, threshold_m: float, slope: float, k: int) -> np.ndarray:
    """`despike` on ground points some places of which hold more than k of them: each point of
    such a stack is compared with the median of its stack (its k nearest are at distance 0
    among them, which of them a tie); the tree keeps k + 1 of each stack, enough for any other
    point's k nearest, so a million coincident points cost what k + 1 do."""
    _, place, count = np.unique(xy, axis=0, return_inverse=True, return_counts=True)
    place = place.reshape(-1)
    rank = np.empty(len(xy), np.int64)
    order = np.argsort(place, kind="stable")
    starts = np.cumsum(count) - count
    rank[order] = np.arange(len(xy)) - np.repeat(starts, count)
    crowded = count[place] > k
    in_tree = ~crowded | (rank <= k)
    tree_xy, tree_z = xy[in_tree], z[in_tree]
    off = np.empty(len(xy))
    allowed = np.full(len(xy), threshold_m)
    query = np.flatnonzero(~crowded)
    if query.size:
        distance, neighbour = _tree(tree_xy).query(xy[query], k=k + 1, workers=-1)
        distance, neighbour = distance[:, 1:], neighbour[:, 1:]          # the point itself first
        off[query] = z[query] - _median_rows(tree_z[neighbour])
        allowed[query] += slope * _median_sorted_rows(distance)
    stacked = np.flatnonzero(crowded)
    if stacked.size:
        z_sorted = z[order]
        medians = np.zeros(len(count))
        for p in np.flatnonzero(count > k):                # few: each holds more than k points
            medians[p] = np.median(z_sorted[starts[p]:starts[p] + count[p]])
        off[stacked] = z[stacked] - medians[place[stacked]]
    out = ground.copy()
    out[index[np.abs(off) > allowed]] = False
    return out


def stacked_drop_m(cell_m: float, slope_p90: float) -> float:
    """The drop below a ground point that `unstack` takes for a second surface [m]: `MIN_DROP_M`,
    or `DROP_SLOPES` cells of `cell_m` [m] at the terrain's 90th-percentile slope [-]."""
    return max(MIN_DROP_M, DROP_SLOPES * cell_m * slope_p90)


def _cells_from_corner(values: np.ndarray, cell_m: float, corner: float) -> np.ndarray:
    """int64 `(n,)` cells `floor((values - corner) / cell_m) + 1` of coordinates `(n,)` [m] (a
    ring of empty cells before the first, at `corner`, the lowest value), through one float
    temporary."""
    scaled = np.subtract(values, corner)
    scaled /= cell_m
    cells = np.floor(scaled, out=scaled).astype(np.int64)
    cells += 1
    return cells


def unstack(xyz_m: np.ndarray, used: np.ndarray, ground: np.ndarray, *, cell_m: float,
            drop_m: float) -> np.ndarray:
    """Ground labels without the points that stand over other returns (the module docstring).

    Args:
      xyz_m: coordinates, float `(n, 3)` [m].
      used: bool `(n,)`, the returns that count (noise and withheld points left out).
      ground: bool `(n,)`, a filter's labels.
      cell_m: the neighbourhood's cell [m] (> 0); a point is compared with the lowest used return
        of its own cell and the 8 around it.
      drop_m: a return more than this below a ground point unmakes it [m].

    Returns:
      bool `(n,)`: `ground` with the stacked points False.
    """
    ground = np.asarray(ground, dtype=bool)
    used = np.asarray(used, dtype=bool)
    if not ground.any() or not used.any():
        return ground.copy()
    xyz = np.asarray(xyz_m, dtype=np.float64)
    either = used | ground
    # cells from the points' corner, as the rule was chosen: a survey's window lays them from its
    # own corner, so near a window's edge its labels may differ from one file's (as the spikes')
    corner = [float(xyz[:, j].min(where=either, initial=np.inf)) for j in range(2)]
    # `_cells_from_corner` of the highest point: floor((v - corner) / cell) never decreases with v
    width, height = (math.floor((float(xyz[:, j].max(where=either, initial=-np.inf)) - corner[j]) / cell_m) + 3
                     for j in range(2))

    def keys(rows) -> np.ndarray:
        """Flat keys int64 `(k,)` of the points `rows`' cells (a ring of empty cells around)."""
        key = _cells_from_corner(xyz[rows, 1], cell_m, corner[1])
        key *= width
        key += _cells_from_corner(xyz[rows, 0], cell_m, corner[0])
        return key

    # the ground points' cells and tops, and the lowest used return of each cell, a slice of
    # points at a time: a survey's window holds millions of points, ground a third of them
    dense = height * width <= 4 * int(np.count_nonzero(either))
    lowest = np.full(height * width, np.inf) if dense else None
    cell, top, on_ground, used_keys, used_z = [], [], [], [], []
    for part in columns.slices(len(ground)):
        rows = np.flatnonzero(either[part]) + part.start        # each point's cell found once
        key, z = keys(rows), xyz[rows, 2]
        mine, theirs = ground[rows], used[rows]
        on_ground.append(rows[mine])
        cell.append(key[mine])
        top.append(z[mine] - drop_m)
        if dense:
            np.minimum.at(lowest, key[theirs], z[theirs])
        else:
            used_keys.append(key[theirs])
            used_z.append(z[theirs])
    cell, top, on_ground = (np.concatenate(parts) for parts in (cell, top, on_ground))
    if dense:
        # a box the points fill: the lowest return of every cell of it, then of the 3 x 3 cells
        # around each (the ring's cells keep +inf), read once per ground point
        stacked = _around(lowest.reshape(-1, width), np.inf, np.min, size=3)[cell] < top
    else:
        # the occupied cells only (sorted keys): a stray point kilometres away adds one cell, not a raster
        cells, slot = np.unique(np.concatenate(used_keys), return_inverse=True)
        lowest = np.full(cells.size, np.inf)
        np.minimum.at(lowest, slot, np.concatenate(used_z))
        stacked = np.zeros(cell.size, dtype=bool)
        for step in (-width - 1, -width, -width + 1, -1, 0, 1, width - 1, width, width + 1):
            near = cell + step
            at = np.minimum(np.searchsorted(cells, near), cells.size - 1)
            stacked |= (cells[at] == near) & (lowest[at] < top)
    out = ground.copy()
    out[on_ground[stacked]] = False
    return out


def guard(xyz_m: np.ndarray, used: np.ndarray, ground: np.ndarray, *, spacing_m: float,
          slope_p90: float) -> np.ndarray:
    """A filter's ground labels bool `(n,)` without stacked points (`unstack`, on cells of the
    point spacing `spacing_m` [m], at least `MIN_CELL_M`, with the drop of the terrain's
    90th-percentile slope `slope_p90` [-]), then without spikes (`despike`); `xyz_m` `(n, 3)`
    [m], `used` bool `(n,)` the returns that count."""
    cell_m = max(MIN_CELL_M, spacing_m)
    ground = unstack(xyz_m, used, ground, cell_m=cell_m, drop_m=stacked_drop_m(cell_m, slope_p90))
    return despike(xyz_m, ground)
