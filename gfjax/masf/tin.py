"""scipy triangulations and queries for MASF (host, outside jit; float64 local metres).

- `delaunay_faces`: the unique triangles of the 3D Delaunay triangulation (Qhull) of the
  potential ground points, each with the one or two vertices opposite it in its adjacent
  tetrahedra; `alpha_shape.triangle_geometry` turns these into alpha intervals.
- `nearest_z`: z of the nearest point in x, y (cKDTree), for the buffer cells.
- `bottom_surface`: the rasterised bottom TIN of the alpha shape's "below" test.

Qhull errors on degenerate input (fewer than 4 points, all coplanar or collinear) never leave
this module: `delaunay_faces` returns None and the caller takes its documented fallback.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

__all__ = ["delaunay_faces", "nearest_z", "bottom_surface"]


def delaunay_faces(xyz_m: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Unique triangles of the 3D Delaunay triangulation of `xyz_m` (float64 `(p, 3)`, metres).

    Returns:
      `(faces, opposite)`: int64 `(f, 3)` vertex indices of each triangle and int64 `(f, 2)`
      indices of the vertex opposite it in each adjacent tetrahedron (`-1` in the second
      column for a triangle on the convex hull). None when the points span no tetrahedron
      (fewer than 4 points, coplanar or collinear input).
    """
    if len(xyz_m) < 4:
        return None
    try:
        tri = Delaunay(xyz_m)
    except (QhullError, ValueError):
        return None
    simplices = tri.simplices.astype(np.int64)
    neighbours = tri.neighbors.astype(np.int64)
    if len(simplices) == 0:
        return None
    tet = np.repeat(np.arange(len(simplices), dtype=np.int64), 4)
    local = np.tile(np.arange(4, dtype=np.int64), len(simplices))
    other = neighbours.reshape(-1)
    keep = (other < 0) | (tet < other)
    tet, local, other = tet[keep], local[keep], other[keep]
    # Face opposite local vertex j of a tetrahedron = its other three vertices.
    face_local = (local[:, None] + np.arange(1, 4, dtype=np.int64)[None, :]) % 4
    faces = simplices[tet[:, None], face_local]
    opposite = np.full((len(tet), 2), -1, dtype=np.int64)
    opposite[:, 0] = simplices[tet, local]
    inner = other >= 0
    back = np.argmax(neighbours[other[inner]] == tet[inner, None], axis=1)
    opposite[inner, 1] = simplices[other[inner], back]
    return faces, opposite


def nearest_z(xy_query_m: np.ndarray, xyz_m: np.ndarray) -> np.ndarray:
    """z of the point of `xyz_m` (float64 `(k, 3)`) nearest in x, y to each query `(q, 2)`."""
    _, nearest = cKDTree(xyz_m[:, :2]).query(xy_query_m, k=1)
    return xyz_m[nearest, 2]


def bottom_surface(xyz_m: np.ndarray, row: np.ndarray, col: np.ndarray, shape: tuple[int, int], *,
                   cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The rasterised bottom TIN of the "below" test (SPEC 4, faster forms).

    Each occupied cell holds the z of its potential ground point (one per cell, so the raster
    is the TIN sampled at the points, up to the offset from point to cell centre); empty cells
    take the nearest occupied cell's z. Cells whose centre lies outside the convex hull of the
    points in x, y are marked outside (a sphere centre there is never below).

    Args:
      xyz_m: float64 `(p, 3)` potential ground points, local metres. row, col: int64 `(p,)`.
      shape: `(h, w)`. cell_m: cell side [m].

    Returns:
      `(z, inside)`: float64 `(h, w)` [m] and bool `(h, w)`.
    """
    h, w = shape
    z = np.zeros(shape)
    occupied = np.zeros(shape, dtype=bool)
    z[row, col] = xyz_m[:, 2]
    occupied[row, col] = True
    if not occupied.all():
        _, (near_r, near_c) = ndi.distance_transform_edt(~occupied, return_indices=True)
        z = z[near_r, near_c]
    try:
        hull = ConvexHull(xyz_m[:, :2])
    except (QhullError, ValueError):
        return z, occupied
    # Scanline fill of the convex hull polygon at the cell-centre rows (h x edges, not h x w x edges).
    ring = xyz_m[hull.vertices, :2]
    start, end = ring, np.roll(ring, -1, axis=0)
    y_centre = (h - 1 - np.arange(h) + 0.5) * cell_m                      # (h,)
    y0, y1 = start[:, 1][None, :], end[:, 1][None, :]
    lo_y, hi_y = np.minimum(y0, y1), np.maximum(y0, y1)
    crosses = (y_centre[:, None] >= lo_y) & (y_centre[:, None] <= hi_y)
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(y1 != y0, (y_centre[:, None] - y0) / (y1 - y0), 0.0)
    x_cross = start[:, 0][None, :] + frac * (end[:, 0] - start[:, 0])[None, :]
    x_min = np.where(crosses, x_cross, np.inf).min(axis=1)
    x_max = np.where(crosses, x_cross, -np.inf).max(axis=1)
    x_centre = (np.arange(w) + 0.5) * cell_m
    inside = (x_centre[None, :] >= x_min[:, None]) & (x_centre[None, :] <= x_max[:, None])
    return z, inside | occupied
