"""DMF host neighbour tables (numpy / scipy `cKDTree`, outside jit).

* `cylinder_table`: the padded `(m, k)` table of each ND_CE's neighbours within a horizontal
  radius (the cylinder C_p of Wu et al. 2025, Sec. 2.3), read by the JAX basal iteration.
  Built on a uniform grid of buckets of side `radius / R` holding one node each (R = 3 for
  ND_CE and r = 3 W: the buckets are the voxel columns): every neighbour lies in the
  `(2R + 1)^2` buckets around a node, so one vectorised gather and one row sort replace a
  KD-tree query. bcts_2 (56,796 ND_CE): 1.7x less CPU than `cKDTree.query(k=33,
  distance_upper_bound)`, 0.050 s vs 0.072 s on 2 idle cores (both multi-threaded), the same DMF
  output (`experiments/dmf_speed.py`, `--identity`). Nodes no bucket size separates, or a grid
  much larger than the node count, use the KD-tree.
* `nearest_node`: the 3D-nearest node of each query point (ND_NG in Sec. 2.3; the point ->
  support-node search of the bidirectional KD-tree engine in Sec. 2.6).
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["NeighbourTable", "cylinder_table", "nearest_node"]

_REACHES = (3, 2, 4, 5, 1)  # buckets of side radius / R: neighbours lie within R buckets per axis
_EDGE = 1e-6               # ... unless a node is this close (x bucket side) to its bucket's edge
_MAX_GRID_PER_NODE = 16    # bucket grids larger than this many buckets per node use the KD-tree
_WORKERS = max(1, min(os.cpu_count() or 1, 8))   # threads sorting the grid's rows


class NeighbourTable(NamedTuple):
    """Fixed-width neighbour lists.

    Attributes:
      index: int32 `(m, k)`; row i lists the nodes within the radius of node i (itself
        included), nearest first (equal distances: lower index first on the grid path); unused
        slots repeat i.
      valid: bool `(m, k)`, True on used slots.
      overflowed: True when some node had more than k neighbours (the farthest were dropped).
    """

    index: np.ndarray
    valid: np.ndarray
    overflowed: bool


def _bound_m(radius_m: float) -> float:
    """The strict upper bound on the distance of a neighbour: `radius_m` plus 1e-9 relative,
    so that a node at exactly `radius_m` (grid-aligned data) is inside."""
    return radius_m * (1 + 1e-9)


def _ring_offsets(reach: int, width: int) -> np.ndarray:
    """Flat offsets of the `(2 reach + 1)^2` buckets around one, nearest buckets first (so the
    candidate rows come nearly sorted by distance and the row sort is cheap)."""
    steps = np.arange(-reach, reach + 1, dtype=np.int64)
    dy, dx = np.meshgrid(steps, steps, indexing="ij")
    order = np.argsort((dy * dy + dx * dx).reshape(-1), kind="stable")
    return (dy * width + dx).reshape(-1)[order]


def _sorted_rows(xy: np.ndarray, rows: np.ndarray, candidates: np.ndarray, bound_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Candidates within `bound_m` (strictly) of each node of `rows`, by distance, then index.

    Args:
      rows: node indices, int64 `(r,)`; candidates: their candidate nodes, int64 `(r, c)`, -1 = none.

    Returns: `(index (r, c) int64, count (r,))`; row i's first count[i] entries are used.
    """
    safe = np.maximum(candidates, 0)
    x, y = np.ascontiguousarray(xy[:, 0]), np.ascontiguousarray(xy[:, 1])   # 1-D gathers: 3x faster
    dx = x[safe] - x[rows][:, None]
    dy = y[safe] - y[rows][:, None]
    d2 = dx * dx + dy * dy                              # what cKDTree compares (p = 2, float64)
    d2 = np.where((candidates >= 0) & (d2 < bound_m * bound_m), d2, np.inf)
    rank = np.argsort(d2, axis=1)                       # rows come nearly sorted (ring order)
    flat = rank + (np.arange(len(rows)) * rank.shape[1])[:, None]
    d2_sorted, index = d2.reshape(-1)[flat], safe.reshape(-1)[flat]
    count = np.isfinite(d2_sorted).sum(axis=1)
    # Rows with equal distances (grid-aligned or quantised data): those neighbours by index.
    ties = (d2_sorted[:, 1:] == d2_sorted[:, :-1]) & np.isfinite(d2_sorted[:, 1:])
    for row in np.flatnonzero(ties.any(axis=1)):
        used = count[row]
        index[row, :used] = index[row, :used][np.lexsort((index[row, :used], d2_sorted[row, :used]))]
    return index, count


def _one_node_buckets(xy: np.ndarray, radius_m: float) -> tuple[int, np.ndarray, np.ndarray, int] | None:
    """The first bucket side `radius_m / R` (R in `_REACHES`) that puts at most one node in a
    bucket: `(R, bucket id (m,), node of bucket, grid width)`, or None (the grid is too large,
    or no R separates the nodes). For ND_CE (one per W x W column) and a radius of R W the
    buckets are the columns."""
    m = len(xy)
    for reach in _REACHES:
        cell = np.floor(xy / (radius_m / reach)).astype(np.int64)
        cell -= cell.min(axis=0)
        frame = reach + 1                                            # empty buckets around
        gw, gh = int(cell[:, 0].max()) + 1 + 2 * frame, int(cell[:, 1].max()) + 1 + 2 * frame
        if gw * gh > _MAX_GRID_PER_NODE * m + 4096:
            return None
        bucket = (cell[:, 1] + frame) * gw + (cell[:, 0] + frame)
        node_of_bucket = np.full(gw * gh, -1, np.int64)
        node_of_bucket[bucket] = np.arange(m)
        if np.count_nonzero(node_of_bucket >= 0) == m:
            return reach, bucket, node_of_bucket, gw
    return None


def _grid_rows(xy: np.ndarray, radius_m: float, bound_m: float) -> tuple[np.ndarray, np.ndarray] | None:
    """`_sorted_rows` of every node from a grid of buckets holding one node each
    (`_one_node_buckets`), or None when there is none (use the KD-tree).

    With bucket side `radius_m / R`, a node farther than `_EDGE` sides from its bucket's edges
    has all its neighbours in the `(2R + 1)^2` buckets around it (|dx| < bound, only 1e-9
    relative above R sides); the few nodes on an edge (quantised coordinates, or neighbours at
    exactly the radius) look one ring farther.
    """
    m = len(xy)
    grid = _one_node_buckets(xy, radius_m)
    if grid is None:
        return None
    reach, bucket, node_of_bucket, gw = grid
    scaled = xy / (radius_m / reach)
    frac = scaled - np.floor(scaled)
    edge = np.any((frac < _EDGE) | (frac > 1 - _EDGE), axis=1)
    tasks = [(rows, reach) for rows in np.array_split(np.flatnonzero(~edge), _WORKERS)]
    tasks.append((np.flatnonzero(edge), reach + 1))

    def rows_of(task):
        rows, r = task
        candidates = node_of_bucket[bucket[rows, None] + _ring_offsets(r, gw)[None, :]]
        return (rows, *_sorted_rows(xy, rows, candidates, bound_m))

    # numpy releases the GIL in the gathers, the arithmetic and the row sorts: on 2 idle
    # cores, 2 threads take the rows of bcts_2 in 0.033 s instead of 0.059 s.
    with ThreadPoolExecutor(len(tasks)) as pool:
        parts = list(pool.map(rows_of, tasks))
    width = max(1, max(int(count.max(initial=0)) for _, _, count in parts))
    index, count = np.zeros((m, width), np.int64), np.zeros(m, np.int64)
    for rows, idx, cnt in parts:
        keep = min(width, idx.shape[1])
        index[rows, :keep], count[rows] = idx[:, :keep], cnt
    return index, count


def _kdtree_rows(xy: np.ndarray, bound_m: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The `_sorted_rows` of the k nearest neighbours by a KD-tree query (equal distances in
    the tree's order)."""
    m = len(xy)
    kq = min(k, m)
    dist, idx = cKDTree(xy).query(xy, k=kq, distance_upper_bound=bound_m, workers=-1)
    dist, idx = np.asarray(dist).reshape(m, kq), np.asarray(idx).reshape(m, kq)
    found = np.isfinite(dist)
    return np.where(found, idx, 0), found.sum(axis=1)


def _pack(index: np.ndarray, count: np.ndarray, *, k: int, shrink: bool, max_width: int | None,
          overflowed: bool) -> NeighbourTable:
    """Rows of sorted neighbours -> the fixed-width table (own index in unused slots)."""
    m = len(count)
    used = np.minimum(count, k)
    if shrink:
        width = 8
        while width < int(used.max()):
            width *= 2
        if max_width is not None and width > max_width:
            width, overflowed = max_width, True
            used = np.minimum(used, width)
        k = width
    own = np.arange(m, dtype=np.int32)[:, None]
    keep = min(k, index.shape[1])
    valid = np.zeros((m, k), bool)
    valid[:, :keep] = np.arange(keep)[None, :] < used[:, None]
    table = np.repeat(own, k, axis=1)
    table[:, :keep] = np.where(valid[:, :keep], index[:, :keep], own)
    return NeighbourTable(index=table, valid=valid, overflowed=overflowed)


def cylinder_table(xy: np.ndarray, *, radius_m: float, k: int, shrink: bool = True,
                   max_width: int | None = None, method: str = "auto") -> NeighbourTable:
    """Neighbours of every node within `radius_m` in x, y (a vertical cylinder).

    Args:
      xy: node positions, float64 `(m, 2)`, metres.
      radius_m: cylinder radius [m] (inclusive).
      k: table width (static for JAX). With one node per W x W column and radius r W,
        `(2 ceil(r) + 1)^2` always suffices (`Config.basal_neighbours`).
      shrink: narrow the table to the next power of two (>= 8) of the largest neighbour count
        (so the JAX sorting network of `basal.sort_rows` applies and stays small).
      max_width: keep at most this many nearest neighbours (a power of two); a node with more
        loses its farthest ones and `overflowed` is set. None = no cap.
      method: "grid" (buckets, see the module docstring), "kdtree" (scipy), or "auto": the
        grid unless the nodes are too sparse or too dense for it. Both give the same table
        except for the order of neighbours at exactly equal distances (the grid: by index).

    Returns: `NeighbourTable`.
    """
    if method not in ("auto", "grid", "kdtree"):
        raise ValueError(f"method must be 'auto', 'grid' or 'kdtree', got {method!r}")
    m = len(xy)
    if m == 0:
        return NeighbourTable(np.zeros((0, k), np.int32), np.zeros((0, k), bool), False)
    if max_width is not None:
        k = min(k, max_width)
    bound_m = _bound_m(radius_m)
    rows = None if method == "kdtree" else _grid_rows(xy, radius_m, bound_m)
    if rows is None and method == "grid":
        raise ValueError(f"cylinder_table: no bucket grid for {m} nodes and radius {radius_m} m "
                         "(no bucket side radius / R holds one node each, or the grid is too sparse)")
    index, count = _kdtree_rows(xy, bound_m, k + 1) if rows is None else rows    # k + 1: overflow
    return _pack(index, count, k=k, shrink=shrink, max_width=max_width, overflowed=bool(np.any(count > k)))


def nearest_node(nodes: np.ndarray, queries: np.ndarray, *, tree: cKDTree | None = None) -> np.ndarray:
    """Index of the 3D-nearest node of each query (ties: scipy's order). The query runs on
    every core (`workers=-1`; the same result).

    Args:
      nodes: float64 `(m, 3)` metres; queries: float64 `(q, 3)` metres.

    Returns: int64 `(q,)` indices into `nodes`.
    """
    tree = cKDTree(nodes) if tree is None else tree
    _, idx = tree.query(queries, k=1, workers=-1)
    return np.asarray(idx, dtype=np.int64)
