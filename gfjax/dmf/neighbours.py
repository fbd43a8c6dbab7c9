"""DMF host KD-tree tables (scipy `cKDTree`, outside jit).

* `cylinder_table`: the padded `(m, k)` table of each ND_CE's neighbours within a horizontal
  radius (the cylinder C_p of Wu et al. 2025, Sec. 2.3), read by the JAX basal iteration.
* `nearest_node`: the 3D-nearest node of each query point (ND_NG in Sec. 2.3; the point ->
  support-node search of the bidirectional KD-tree engine in Sec. 2.6).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["NeighbourTable", "cylinder_table", "nearest_node"]


class NeighbourTable(NamedTuple):
    """Fixed-width neighbour lists.

    Attributes:
      index: int32 `(m, k)`; row i lists the nodes within the radius of node i (itself
        included), nearest first; unused slots repeat i.
      valid: bool `(m, k)`, True on used slots.
      overflowed: True when some node had more than k neighbours (the farthest were dropped).
    """

    index: np.ndarray
    valid: np.ndarray
    overflowed: bool


def cylinder_table(xy: np.ndarray, *, radius_m: float, k: int, shrink: bool = True,
                   max_width: int | None = None) -> NeighbourTable:
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

    Returns: `NeighbourTable`.
    """
    m = len(xy)
    if m == 0:
        return NeighbourTable(np.zeros((0, k), np.int32), np.zeros((0, k), bool), False)
    tree = cKDTree(xy)
    if max_width is not None:
        k = min(k, max_width)                      # the query needs no more (one extra: overflow)
    kq = min(k + 1, m)
    dist, idx = tree.query(xy, k=kq, distance_upper_bound=radius_m * (1 + 1e-9))
    dist, idx = np.atleast_2d(dist), np.atleast_2d(idx)
    if kq == 1:
        dist, idx = dist.reshape(m, 1), idx.reshape(m, 1)
    found = np.isfinite(dist)
    overflowed = bool(kq > k and found[:, k].any())
    found, idx = found[:, :k], idx[:, :k]
    if shrink:
        used = int(found.sum(axis=1).max())
        width = 8
        while width < used:
            width *= 2
        if max_width is not None and width > max_width:
            width, overflowed = max_width, True
        found, idx = found[:, :min(width, found.shape[1])], idx[:, :min(width, idx.shape[1])]
        k = width
    own = np.arange(m, dtype=np.int64)[:, None]
    index = np.where(found, idx, own).astype(np.int32)
    if index.shape[1] < k:
        pad = k - index.shape[1]
        index = np.concatenate([index, np.repeat(own.astype(np.int32), pad, axis=1)], axis=1)
        found = np.concatenate([found, np.zeros((m, pad), bool)], axis=1)
    return NeighbourTable(index=index, valid=found, overflowed=overflowed)


def nearest_node(nodes: np.ndarray, queries: np.ndarray, *, tree: cKDTree | None = None) -> np.ndarray:
    """Index of the 3D-nearest node of each query (ties: scipy's order).

    Args:
      nodes: float64 `(m, 3)` metres; queries: float64 `(q, 3)` metres.

    Returns: int64 `(q,)` indices into `nodes`.
    """
    tree = cKDTree(nodes) if tree is None else tree
    _, idx = tree.query(queries, k=1)
    return np.asarray(idx, dtype=np.int64)
