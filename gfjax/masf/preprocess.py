"""MASF preprocessing: potential ground points by the extended local minimum (Cao et al. 2024,
Sec. 2.1, citing Chen et al. 2013) plus a neighbourhood low-outlier test (SPEC section 4.1).

Host numpy / scipy.ndimage: one sort of the points by (cell, z) and two small min filters.
Grid convention of docs/ARCHITECTURE.md: local `x in [0, w * grid_m)`, `y in [0, h * grid_m)`,
`row = h - 1 - floor(y / grid_m)` (row 0 = north), `col = floor(x / grid_m)`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Preprocessed", "grid_shape", "potential_ground"]


class Preprocessed(NamedTuple):
    """Potential ground points of a cloud, one per occupied cell at most.

    Attributes:
      index: int64 `(p,)`, indices into the local points of the potential ground points,
        sorted by cell (row-major, row 0 = north).
      row, col: int64 `(p,)`, their cells.
      shape: `(h, w)` of the grid.
      occupied: bool `(h, w)`, cells holding at least one point.
      gap_outliers: int, points removed by the per-cell gap rule that were their cell's lowest.
      neighbour_outliers: bool `(h, w)`, cells whose potential ground point the neighbourhood
        test removed (they hold no potential ground point).
    """

    index: np.ndarray
    row: np.ndarray
    col: np.ndarray
    shape: tuple[int, int]
    occupied: np.ndarray
    gap_outliers: int
    neighbour_outliers: np.ndarray


def grid_shape(xy_m: np.ndarray, *, grid_m: float) -> tuple[int, int]:
    """`(h, w)` of the grid covering local `xy_m >= 0` (float64 `(n, 2)`, metres)."""
    if len(xy_m) == 0:
        return (1, 1)
    top = np.floor(xy_m.max(axis=0) / grid_m).astype(np.int64) + 1
    return int(top[1]), int(top[0])


def potential_ground(xyz_m: np.ndarray, *, grid_m: float, outlier_gap_m: float,
                     neighbour_drop_m: float, max_cluster_cells: int = 1, neighbour_test: bool = True) -> Preprocessed:
    """Select one potential ground point per occupied cell and drop low outliers.

    Extended local minimum (Sec. 2.1): the points of a cell, sorted by z, are walked upwards;
    a point whose gap to the next point of its cell exceeds `outlier_gap_m` is an outlier; the
    first point that is not is the cell's potential ground point (the top point of a cell is
    never an outlier, so every occupied cell has one). Then the neighbourhood test (R): a
    connected group of at most `max_cluster_cells` cells (linked within 5x5 when their z differ
    by at most `neighbour_drop_m`) that lies more than `neighbour_drop_m` below every occupied
    cell around it is a low outlier (`_low_clusters`). With the default single cell this is
    SPEC 4.1's rule, except that all occupied cells of the 5x5 window count (SPEC: the 3x3
    ring, the 5x5 one only where the 3x3 ring is empty).

    Args:
      xyz_m: float64 `(n, 3)` local metres, `x, y >= 0` (subtract the minimum corner first).
      grid_m: cell side [m]. outlier_gap_m, neighbour_drop_m: thresholds [m].
      max_cluster_cells: largest group of cells the neighbourhood test removes together.
      neighbour_test: False leaves the neighbourhood test out (the per-cell gap rule alone).

    Returns:
      A `Preprocessed`. The choice depends only on the coordinates, never on point order:
      ties in z are broken by y then x.
    """
    shape = grid_shape(xyz_m[:, :2], grid_m=grid_m)
    h, w = shape
    occupied = np.zeros(shape, dtype=bool)
    if len(xyz_m) == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Preprocessed(empty, empty, empty, shape, occupied, 0, np.zeros(shape, dtype=bool))
    col = np.floor(xyz_m[:, 0] / grid_m).astype(np.int64)
    row = h - 1 - np.floor(xyz_m[:, 1] / grid_m).astype(np.int64)
    cell = row * w + col
    order = np.lexsort((xyz_m[:, 0], xyz_m[:, 1], xyz_m[:, 2], cell))
    cell_sorted = cell[order]
    z_sorted = xyz_m[order, 2]
    same_next = np.zeros(len(order), dtype=bool)
    same_next[:-1] = cell_sorted[1:] == cell_sorted[:-1]
    gap = np.zeros(len(order))
    gap[:-1] = z_sorted[1:] - z_sorted[:-1]
    outlier = same_next & (gap > outlier_gap_m)
    candidates = np.flatnonzero(~outlier)
    cand_cell = cell_sorted[candidates]
    first = np.ones(len(candidates), dtype=bool)
    first[1:] = cand_cell[1:] != cand_cell[:-1]
    chosen = order[candidates[first]]
    lowest = np.ones(len(order), dtype=bool)
    lowest[1:] = cell_sorted[1:] != cell_sorted[:-1]
    gap_outliers = int(np.count_nonzero(outlier & lowest))

    p_row, p_col = row[chosen], col[chosen]
    occupied[p_row, p_col] = True
    z_grid = np.full(shape, np.inf)
    z_grid[p_row, p_col] = xyz_m[chosen, 2]
    if neighbour_test:
        low = _low_clusters(z_grid, occupied, drop_m=neighbour_drop_m, max_cells=max_cluster_cells)
    else:
        low = np.zeros(shape, dtype=bool)
    keep = ~low[p_row, p_col]
    return Preprocessed(chosen[keep], p_row[keep], p_col[keep], shape, occupied, gap_outliers, low)


# Offsets (dr, dc) covering the 5x5 neighbourhood once per unordered pair of cells.
_HALF_5X5 = [(dr, dc) for dr in range(0, 3) for dc in range(-2, 3) if dr > 0 or dc > 0]


def _low_clusters(z_grid: np.ndarray, occupied: np.ndarray, *, drop_m: float, max_cells: int) -> np.ndarray:
    """Cells of low-outlier clusters: pits in the potential-ground surface.

    Occupied cells within the 5x5 neighbourhood of each other are linked when their z differ
    by at most `drop_m`; a connected cluster of at most `max_cells` cells whose every link to
    another cluster goes up by more than `drop_m` (and that has such a link) is a low outlier.
    For a single cell this is SPEC 4.1's rule (more than `drop_m` below the lowest occupied
    neighbour); clusters catch the patches of multipath points that sit together, metres
    below the ground around them (ISPRS samp41), which the per-cell rule cannot see.

    Returns bool `(h, w)`.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, w = z_grid.shape
    ids = np.full((h, w), -1, dtype=np.int64)
    cells = np.flatnonzero(occupied.reshape(-1))
    ids.reshape(-1)[cells] = np.arange(len(cells))
    z_cell = z_grid.reshape(-1)[cells]
    heads, tails = [], []
    for dr, dc in _HALF_5X5:
        c0, c1 = max(0, -dc), w - max(0, dc)
        a = ids[:h - dr, c0:c1]
        b = ids[dr:, c0 + dc:c1 + dc]
        pair = (a >= 0) & (b >= 0)
        heads.append(a[pair])
        tails.append(b[pair])
    head = np.concatenate(heads)
    tail = np.concatenate(tails)
    linked = np.abs(z_cell[head] - z_cell[tail]) <= drop_m
    graph = coo_matrix((np.ones(int(linked.sum()), dtype=np.int8), (head[linked], tail[linked])),
                       shape=(len(cells), len(cells)))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    across = label[head] != label[tail]
    lower_head = z_cell[head] < z_cell[tail]
    has_up = np.zeros(len(size), dtype=bool)
    has_down = np.zeros(len(size), dtype=bool)
    has_up[label[head[across & lower_head]]] = True
    has_down[label[tail[across & lower_head]]] = True
    has_up[label[tail[across & ~lower_head]]] = True
    has_down[label[head[across & ~lower_head]]] = True
    pit = has_up & ~has_down & (size <= max_cells)
    low = np.zeros((h, w), dtype=bool)
    low.reshape(-1)[cells[pit[label]]] = True
    return low
