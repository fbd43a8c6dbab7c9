"""scipy triangulations and queries for MASF (host, outside jit; float64 local metres).

- `delaunay_faces`: the unique triangles of the 3D Delaunay triangulation (Qhull) of the
  potential ground points, each with the one or two vertices opposite it in its adjacent
  tetrahedra; `alpha_shape.triangle_geometry` turns these into alpha intervals.
- `GroundTin`: the 2D TIN (Delaunay in x, y) of the ground points of the multiscale TIN
  densification (Sec. 2.4), with the perpendicular distance of points to the facet under them.
- `nearest_z`: z of the nearest point in x, y (cKDTree), for the buffer cells.
- `bottom_surface`: the rasterised bottom TIN of the alpha shape's "below" test.

Qhull errors on degenerate input (fewer than 4 points, all coplanar or collinear) never leave
this module: `delaunay_faces` returns None and the caller takes its documented fallback.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi
from scipy.spatial import ConvexHull, Delaunay, QhullError, cKDTree

__all__ = ["delaunay_faces", "GroundTin", "nearest_z", "bottom_surface"]


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


class GroundTin:
    """2D Delaunay TIN of ground points and the point-to-facet distance (Sec. 2.4, Fig. 7a).

    Point location is a vectorised visibility walk (start at a triangle of the nearest
    vertex, step across the edge with the most negative barycentric coordinate) in plain
    numpy: scipy's `find_simplex` first computes barycentric transforms with one LAPACK call
    per triangle, which is slow, and very slow under a threaded BLAS on a busy machine.

    Args:
      xyz_m: float64 `(k, 3)` local metres, `k >= 3` and not all collinear in x, y (the
        densification always includes the buffer cells around the grid, so it never is).
    """

    MAX_STEPS = 256

    def __init__(self, xyz_m: np.ndarray) -> None:
        self.xyz_m = np.asarray(xyz_m, dtype=np.float64)
        self._tri = Delaunay(self.xyz_m[:, :2])
        self._tree = cKDTree(self.xyz_m[:, :2])

    def locate(self, xy_m: np.ndarray) -> np.ndarray:
        """Index of the triangle holding each point `(q, 2)`, `-1` outside the hull; int64 `(q,)`."""
        simplices, neighbours = self._tri.simplices, self._tri.neighbors
        xy = self.xyz_m[:, :2]
        _, nearest = self._tree.query(xy_m, k=1)
        current = self._tri.vertex_to_simplex[nearest].astype(np.int64)
        found = np.full(len(xy_m), -1, dtype=np.int64)
        active = np.arange(len(xy_m))
        for _ in range(self.MAX_STEPS):
            if len(active) == 0:
                break
            corners = xy[simplices[current[active]]]                       # (a, 3, 2)
            q = xy_m[active][:, None, :]
            nxt, after = np.roll(corners, -1, axis=1), np.roll(corners, -2, axis=1)
            # orientation of (v_{j+1}, v_{j+2}, q): the barycentric weight of vertex j, unnormalised
            weight = ((nxt[..., 0] - q[..., 0]) * (after[..., 1] - q[..., 1])
                      - (nxt[..., 1] - q[..., 1]) * (after[..., 0] - q[..., 0]))
            area = weight.sum(axis=1, keepdims=True)
            weight = weight / area
            worst = np.argmin(weight, axis=1)
            inside = weight[np.arange(len(active)), worst] >= -1e-12
            found[active[inside]] = current[active[inside]]
            step = active[~inside]
            current[step] = neighbours[current[step], worst[~inside]]
            outside = current[step] < 0
            active = step[~outside]
        for start in range(0, len(active), 16):              # not reached in MAX_STEPS: rare
            chunk = active[start:start + 16]
            found[chunk] = self._brute_force(xy_m[chunk])
        return found

    def _brute_force(self, xy_m: np.ndarray) -> np.ndarray:
        corners = self.xyz_m[:, :2][self._tri.simplices]                   # (t, 3, 2)
        nxt, after = np.roll(corners, -1, axis=1)[None], np.roll(corners, -2, axis=1)[None]
        q = xy_m[:, None, None, :]
        weight = ((nxt[..., 0] - q[..., 0]) * (after[..., 1] - q[..., 1])
                  - (nxt[..., 1] - q[..., 1]) * (after[..., 0] - q[..., 0]))   # (c, t, 3)
        weight = weight / weight.sum(axis=2, keepdims=True)
        inside = (weight >= -1e-12).all(axis=2)
        return np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)

    def distance_m(self, xyz_m: np.ndarray, *, nearest_facet: bool = False) -> np.ndarray:
        """Distance of each point to the TIN (Sec. 2.4, Fig. 7a).

        Args:
          xyz_m: float64 `(q, 3)` local metres.
          nearest_facet: False (SPEC 4.4): perpendicular distance to the plane of the facet
            under the point. True (the paper's words, "the distance between P and its nearest
            TIN facet"): the 3D point-to-triangle distance, smallest over the facet under the
            point and its three edge neighbours.

        Returns:
          float64 `(q,)` [m], `inf` for a point outside the TIN's x, y hull.
        """
        xyz_m = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        distance = np.full(len(xyz_m), np.inf)
        if len(xyz_m) == 0:
            return distance
        simplex = self.locate(xyz_m[:, :2])
        inside = simplex >= 0
        points = xyz_m[inside]
        under = simplex[inside]
        if not nearest_facet:
            corners = self.xyz_m[self._tri.simplices[under]]                    # (q', 3, 3)
            normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            distance[inside] = np.abs(np.einsum("qk,qk->q", points - corners[:, 0], normal))
            return distance
        best = _point_triangle_distance(points, self.xyz_m[self._tri.simplices[under]])
        for side in range(3):
            other = self._tri.neighbors[under, side]
            has = other >= 0
            d = _point_triangle_distance(points[has], self.xyz_m[self._tri.simplices[other[has]]])
            best[has] = np.minimum(best[has], d)
        distance[inside] = best
        return distance


def _point_triangle_distance(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """3D distance from points `(q, 3)` to triangles `(q, 3, 3)` (the closest point may lie on
    the face, an edge or a vertex), float64 `(q,)`."""
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    height = np.einsum("qk,qk->q", points - a, normal)
    foot = points - height[:, None] * normal
    over_face = np.ones(len(points), dtype=bool)
    for u, v in ((a, b), (b, c), (c, a)):
        over_face &= np.einsum("qk,qk->q", np.cross(v - u, foot - u), normal) >= 0
    edge = np.full(len(points), np.inf)
    for u, v in ((a, b), (b, c), (c, a)):
        uv = v - u
        t = np.clip(np.einsum("qk,qk->q", points - u, uv) / np.einsum("qk,qk->q", uv, uv), 0.0, 1.0)
        edge = np.minimum(edge, np.linalg.norm(points - (u + t[:, None] * uv), axis=1))
    return np.where(over_face, np.abs(height), edge)


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
