"""Batch insertion of points into a 2D Delaunay triangulation (host numpy + one small Qhull call).

Bowyer-Watson in batches: the triangles whose circumcircle strictly contains one of the new
points (the *conflict* triangles, found by a breadth-first walk out from the triangle holding
each point) are exactly those that the points destroy; every other triangle survives. The
cavity they leave is re-triangulated from the small point set `S` = cavity vertices + new
points: every new triangle has its vertices in `S` and an empty circumcircle, so it is also a
triangle of `DT(S)`, and the triangles of `DT(S)` inside the cavity (flood-filled from the
cavity's boundary edges) are the new triangles. In general position the result is the
Delaunay triangulation of all points, triangle for triangle (tests compare with a full Qhull
run). Co-circular ties (LiDAR coordinates on a centimetre lattice have them), where the
Delaunay triangulation is not unique: a triangle with a new point on its circumcircle (within
a relative `TIE_TOL`) joins the cavity, and a cavity wall that `DT(S)` triangulates across
pulls the triangle behind it into the cavity too (`MAX_GROWTH` times); the result is again a
Delaunay triangulation, possibly resolving a tie otherwise than Qhull would. `insert` returns
None when the re-triangulation still does not tile the cavity, and the caller re-triangulates
everything.

Arrays: `xy_m` float64 `(v, 2)` vertices [m]; `simplices` int64 `(t, 3)` counter-clockwise;
`neighbours` int64 `(t, 3)`, the triangle across the edge opposite vertex `j` (`-1`: hull).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import Delaunay, QhullError

__all__ = ["Spliced", "counter_clockwise", "conflicts", "insert", "TIE_TOL", "MAX_GROWTH"]

TIE_TOL = 1e-12     # incircle determinant relative to its scale (|d|^4) counted as a tie
MAX_GROWTH = 4      # times a cavity may grow across walls that DT(S) does not keep


class Spliced(NamedTuple):
    """A triangulation after a batch insertion.

    Attributes:
      simplices, neighbours: int64 `(t', 3)`; triangles that survived keep their ids, new ones
        reuse the destroyed ids (in increasing order) and then append.
      new_ids: int64 `(c,)` ids of the new triangles.
      destroyed: bool `(t,)` over the old ids: the triangle was replaced.
    """

    simplices: np.ndarray
    neighbours: np.ndarray
    new_ids: np.ndarray
    destroyed: np.ndarray


def _signed_area2(corners: np.ndarray) -> np.ndarray:
    """Twice the signed area of triangles `(t, 3, 2)`, positive counter-clockwise."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def counter_clockwise(xy_m: np.ndarray, simplices: np.ndarray, neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Qhull's simplices reordered counter-clockwise (vertices 1 and 2 and their neighbours swapped)."""
    simplices = simplices.astype(np.int64)
    neighbours = neighbours.astype(np.int64)
    flip = _signed_area2(xy_m[simplices]) < 0
    simplices[flip] = simplices[flip][:, [0, 2, 1]]
    neighbours[flip] = neighbours[flip][:, [0, 2, 1]]
    return simplices, neighbours


def _in_conflict(corners: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Where `q` `(c, 2)` lies inside the circumcircle of counter-clockwise triangles `(c, 3, 2)`,
    or on it within the relative tolerance `TIE_TOL`; bool `(c,)`."""
    d = corners - q[:, None, :]
    lift = (d * d).sum(axis=2)
    det = (d[:, 0, 0] * (d[:, 1, 1] * lift[:, 2] - lift[:, 1] * d[:, 2, 1])
           - d[:, 0, 1] * (d[:, 1, 0] * lift[:, 2] - lift[:, 1] * d[:, 2, 0])
           + lift[:, 0] * (d[:, 1, 0] * d[:, 2, 1] - d[:, 1, 1] * d[:, 2, 0]))
    return det > -TIE_TOL * lift.max(axis=1) ** 2


def conflicts(xy_m: np.ndarray, simplices: np.ndarray, neighbours: np.ndarray, q_xy_m: np.ndarray,
              facet: np.ndarray) -> np.ndarray:
    """Triangles whose circumcircle contains one of the points `q_xy_m` `(m, 2)` (ties included).

    `facet` int64 `(m,)` is the triangle holding each point. The conflict triangles of a point
    are edge-connected and include its own (Bowyer-Watson), so a breadth-first walk over
    (point, triangle) pairs finds them all. Returns the sorted unique triangle ids, int64.
    """
    n_tri = np.int64(len(simplices))
    front_q, front_t = np.arange(len(q_xy_m), dtype=np.int64), facet.astype(np.int64)
    seen = np.unique(front_q * n_tri + front_t)
    found = [front_t]
    while len(front_q):
        cand_q = np.repeat(front_q, 3)
        cand_t = neighbours[front_t].reshape(-1)
        key = np.unique(cand_q[cand_t >= 0] * n_tri + cand_t[cand_t >= 0])
        key = key[~np.isin(key, seen, assume_unique=True)]
        seen = np.union1d(seen, key)
        cand_q, cand_t = key // n_tri, key % n_tri
        hit = _in_conflict(xy_m[simplices[cand_t]], q_xy_m[cand_q])
        front_q, front_t = cand_q[hit], cand_t[hit]
        found.append(front_t)
    return np.unique(np.concatenate(found))


def insert(xy_m: np.ndarray, simplices: np.ndarray, neighbours: np.ndarray, n_new: int,
           facet: np.ndarray) -> Spliced | None:
    """Insert the last `n_new` vertices of `xy_m` (float64 `(v, 2)`) into the triangulation.

    Args:
      xy_m: every vertex, the new ones last; they lie strictly inside the hull, at distinct
        positions that hold no old vertex.
      simplices, neighbours: the triangulation of the old vertices (counter-clockwise).
      n_new: number of new vertices.
      facet: int64 `(n_new,)` the old triangle holding each new vertex.

    Returns:
      The `Spliced` triangulation, or None when the cavity's re-triangulation does not tile the
      cavity exactly (the caller re-triangulates all vertices).
    """
    new_v = np.arange(len(xy_m) - n_new, len(xy_m), dtype=np.int64)
    cavity = conflicts(xy_m, simplices, neighbours, xy_m[new_v], facet)
    for _ in range(MAX_GROWTH + 1):
        filled = _fill(xy_m, simplices, neighbours, new_v, cavity)
        if isinstance(filled, Spliced) or len(filled) == 0:
            return filled if isinstance(filled, Spliced) else None
        cavity = np.union1d(cavity, filled)
    return None


def _fill(xy_m, simplices, neighbours, new_v, cavity) -> Spliced | np.ndarray:
    """Re-triangulate `cavity` (sorted int64 triangle ids) with the new vertices `new_v` inside.

    Returns the `Spliced` triangulation, or the triangles behind the cavity walls that `DT(S)`
    does not keep (to add to the cavity; empty when growing cannot help).
    """
    destroyed = np.zeros(len(simplices), dtype=bool)
    destroyed[cavity] = True
    # Directed boundary edges of the cavity, counter-clockwise as seen from inside it.
    side = np.tile(np.arange(3), len(cavity))
    owner = np.repeat(cavity, 3)
    outside = neighbours[owner, side]
    wall = (outside < 0) | ~destroyed[np.maximum(outside, 0)]
    owner, side, outside = owner[wall], side[wall], outside[wall]
    wall_key = simplices[owner, (side + 1) % 3] * np.int64(len(xy_m)) + simplices[owner, (side + 2) % 3]
    # DT(S) of the cavity's vertices and the new points.
    s_ids = np.union1d(simplices[cavity].reshape(-1), new_v)
    local_xy = xy_m[s_ids] - xy_m[s_ids].mean(axis=0)
    try:
        tri = Delaunay(local_xy)
    except (QhullError, ValueError):
        return np.zeros(0, dtype=np.int64)
    l_simp, l_nbr = counter_clockwise(local_xy, tri.simplices, tri.neighbors)
    g_simp = s_ids[l_simp]
    l_key = (g_simp[:, [1, 2, 0]] * np.int64(len(xy_m)) + g_simp[:, [2, 0, 1]]).reshape(-1)   # edge opposite j
    order = np.argsort(l_key)
    pos = np.minimum(np.searchsorted(l_key[order], wall_key), len(order) - 1)
    missing = l_key[order][pos] != wall_key
    if missing.any():                                  # DT(S) triangulates across a wall (a tie)
        return np.unique(outside[missing & (outside >= 0)])
    wall_slot = order[pos]                             # flat (local triangle, side) of each wall
    is_wall = np.zeros(l_key.shape, dtype=bool)
    is_wall[wall_slot] = True
    is_wall = is_wall.reshape(-1, 3)
    inside = np.zeros(len(l_simp), dtype=bool)
    front = np.unique(wall_slot // 3)
    inside[front] = True
    while len(front):
        step = np.where(is_wall[front], -1, l_nbr[front]).reshape(-1)
        step = np.unique(step[step >= 0])
        front = step[~inside[step]]
        inside[front] = True
    kept = np.flatnonzero(inside)
    area_old = _signed_area2(xy_m[simplices[cavity]]).sum()
    area_new = _signed_area2(local_xy[l_simp[kept]]).sum()
    if ((~is_wall[kept] & (l_nbr[kept] < 0)).any() or len(kept) != len(cavity) + 2 * len(new_v)
            or not np.isclose(area_new, area_old, rtol=1e-9, atol=0.0)):
        return np.zeros(0, dtype=np.int64)             # the walls do not enclose a tiling of the cavity
    new_ids = np.concatenate([cavity, len(simplices) + np.arange(len(kept) - len(cavity), dtype=np.int64)])
    global_id = np.full(len(l_simp), -1, dtype=np.int64)
    global_id[kept] = new_ids
    extra = np.zeros((len(kept) - len(cavity), 3), dtype=np.int64)
    out_simp, out_nbr = np.concatenate([simplices, extra]), np.concatenate([neighbours, extra])
    out_simp[new_ids] = g_simp[kept]
    out_nbr[new_ids] = global_id[np.maximum(l_nbr[kept], 0)]    # inner edges (walls are set below)
    wall_tri, wall_side = wall_slot // 3, wall_slot % 3
    out_nbr[global_id[wall_tri], wall_side] = outside
    across = outside >= 0
    back_side = np.argmax(neighbours[outside[across]] == owner[across, None], axis=1)
    out_nbr[outside[across], back_side] = global_id[wall_tri[across]]
    return Spliced(out_simp, out_nbr, new_ids, destroyed)
