"""The 2D TIN of MASF's multiscale densification (Cao et al. 2024, Sec. 2.4, Fig. 7a). Host numpy.

`GroundTin` is a Delaunay triangulation in x, y of ground points (Qhull once, then batch
insertions, `insertion.insert`), with point location by a vectorised visibility walk and the
point-to-facet distance of the densification test. It is immutable: `insert` returns a new TIN
and says which old triangles changed, so a caller retests only the points over them.
"""
from __future__ import annotations

import functools

import numpy as np
from scipy.spatial import Delaunay, cKDTree

from gfjax.masf import insertion

__all__ = ["GroundTin", "point_triangle_distance"]


class GroundTin:
    """2D Delaunay TIN of ground points and the point-to-facet distance (Sec. 2.4, Fig. 7a).

    Point location is a vectorised visibility walk (start at a triangle of the nearest vertex,
    or at a given triangle; step across the edge with the most negative barycentric
    coordinate) in plain numpy: scipy's `find_simplex` first computes barycentric transforms
    with one LAPACK call per triangle, which is slow under a threaded BLAS on a busy machine.

    Args:
      xyz_m: float64 `(k, 3)` local metres, `k >= 3` and not all collinear in x, y (the
        densification always includes the buffer cells around the grid, so it never is).

    Attributes:
      xyz_m: float64 `(k, 3)` the vertices [m].
      simplices: int64 `(t, 3)` counter-clockwise vertex ids of the triangles.
      neighbours: int64 `(t, 3)` the triangle across the edge opposite vertex `j`, `-1` on the hull.
      vertex_to_simplex: int64 `(k,)` a triangle holding each vertex.
      rebuilds: how many insertions fell back to a full triangulation (co-circular ties).
    """

    MAX_STEPS = 256

    def __init__(self, xyz_m: np.ndarray) -> None:
        xyz_m = np.asarray(xyz_m, dtype=np.float64)
        tri = Delaunay(xyz_m[:, :2])
        simplices, neighbours = insertion.counter_clockwise(xyz_m[:, :2], tri.simplices, tri.neighbors)
        self._set(xyz_m, simplices, neighbours, rebuilds=0)

    def _set(self, xyz_m, simplices, neighbours, *, rebuilds: int) -> None:
        self.xyz_m, self.simplices, self.neighbours, self.rebuilds = xyz_m, simplices, neighbours, rebuilds
        self.vertex_to_simplex = np.full(len(xyz_m), -1, dtype=np.int64)
        self.vertex_to_simplex[simplices.reshape(-1)] = np.repeat(np.arange(len(simplices), dtype=np.int64), 3)

    @functools.cached_property
    def _tree(self) -> cKDTree:
        return cKDTree(self.xyz_m[:, :2])

    def insert(self, xyz_m: np.ndarray, facet: np.ndarray, *,
               retriangulate: bool = False) -> tuple[GroundTin, np.ndarray]:
        """The TIN with the points `xyz_m` (float64 `(m, 3)`) added as vertices.

        Args:
          xyz_m: new vertices, strictly inside the TIN's x, y hull, none at the x, y of a vertex.
          facet: int64 `(m,)` the triangle under each (from `locate` or `measure`).
          retriangulate: triangulate all vertices again with Qhull (the reference path).

        Returns:
          `(tin, changed)`: the new TIN (old vertices keep their ids, the new ones follow) and
          bool `(t,)` over the old triangle ids, True where the triangle is no longer in the
          new TIN under the same id (all True after a full re-triangulation).
        """
        xyz_all = np.concatenate([self.xyz_m, np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)])
        out = GroundTin.__new__(GroundTin)
        if len(xyz_all) == len(self.xyz_m):
            out._set(self.xyz_m, self.simplices, self.neighbours, rebuilds=self.rebuilds)
            return out, np.zeros(len(self.simplices), dtype=bool)
        spliced = None if retriangulate else insertion.insert(
            xyz_all[:, :2], self.simplices, self.neighbours, len(xyz_all) - len(self.xyz_m),
            np.asarray(facet, dtype=np.int64))
        if spliced is None:
            out = GroundTin(xyz_all)
            out.rebuilds = self.rebuilds + (not retriangulate)
            return out, np.ones(len(self.simplices), dtype=bool)
        out._set(xyz_all, spliced.simplices, spliced.neighbours, rebuilds=self.rebuilds)
        return out, spliced.destroyed

    def with_heights(self, ids: np.ndarray, z_m: np.ndarray) -> GroundTin:
        """The same triangulation with the vertices `ids` (int64 `(r,)`) at heights `z_m`
        (float64 `(r,)` [m]); x, y and so the triangles are unchanged."""
        xyz_m = self.xyz_m.copy()
        xyz_m[ids, 2] = z_m
        out = GroundTin.__new__(GroundTin)
        out._set(xyz_m, self.simplices, self.neighbours, rebuilds=self.rebuilds)
        if "_tree" in self.__dict__:
            out.__dict__["_tree"] = self.__dict__["_tree"]       # x, y unchanged: the same tree
        return out

    def locate(self, xy_m: np.ndarray, *, start: np.ndarray | None = None) -> np.ndarray:
        """Index of the triangle holding each point `(q, 2)`, `-1` outside the hull; int64 `(q,)`.

        `start`: int64 `(q,)` triangles to start the walk at (default: one of the nearest vertex).
        """
        xy = self.xyz_m[:, :2]
        if start is None:
            _, nearest = self._tree.query(xy_m, k=1)
            start = self.vertex_to_simplex[nearest]
        current = np.array(start, dtype=np.int64)
        found = np.full(len(xy_m), -1, dtype=np.int64)
        active = np.arange(len(xy_m))
        for _ in range(self.MAX_STEPS):
            if len(active) == 0:
                break
            corners = xy[self.simplices[current[active]]]                  # (a, 3, 2)
            q = xy_m[active][:, None, :]
            nxt, after = np.roll(corners, -1, axis=1), np.roll(corners, -2, axis=1)
            # orientation of (v_{j+1}, v_{j+2}, q): the barycentric weight of vertex j, unnormalised
            weight = ((nxt[..., 0] - q[..., 0]) * (after[..., 1] - q[..., 1])
                      - (nxt[..., 1] - q[..., 1]) * (after[..., 0] - q[..., 0]))
            weight = weight / weight.sum(axis=1, keepdims=True)
            worst = np.argmin(weight, axis=1)
            inside = weight[np.arange(len(active)), worst] >= -1e-12
            found[active[inside]] = current[active[inside]]
            step = active[~inside]
            current[step] = self.neighbours[current[step], worst[~inside]]
            active = step[current[step] >= 0]
        for first in range(0, len(active), 16):               # not reached in MAX_STEPS: rare
            chunk = active[first:first + 16]
            found[chunk] = self._brute_force(xy_m[chunk])
        return found

    def _brute_force(self, xy_m: np.ndarray) -> np.ndarray:
        corners = self.xyz_m[:, :2][self.simplices]                        # (t, 3, 2)
        nxt, after = np.roll(corners, -1, axis=1)[None], np.roll(corners, -2, axis=1)[None]
        q = xy_m[:, None, None, :]
        weight = ((nxt[..., 0] - q[..., 0]) * (after[..., 1] - q[..., 1])
                  - (nxt[..., 1] - q[..., 1]) * (after[..., 0] - q[..., 0]))   # (c, t, 3)
        weight = weight / weight.sum(axis=2, keepdims=True)
        inside = (weight >= -1e-12).all(axis=2)
        return np.where(inside.any(axis=1), np.argmax(inside, axis=1), -1)

    def measure(self, xyz_m: np.ndarray, *, nearest_facet: bool = False,
                start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Distance of each point to the TIN and the facet under it (Sec. 2.4, Fig. 7a).

        Args:
          xyz_m: float64 `(q, 3)` local metres.
          nearest_facet: False (SPEC 4.4): perpendicular distance to the plane of the facet
            under the point. True (the paper's words, "the distance between P and its nearest
            TIN facet"): the 3D point-to-triangle distance, smallest over the facet under the
            point and its three edge neighbours.
          start: optional int64 `(q,)` triangles to start the point location at.

        Returns:
          `(distance, facet)`: float64 `(q,)` [m], `inf` outside the TIN's x, y hull, and
          int64 `(q,)` the triangle under each point (`-1` outside).
        """
        xyz_m = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        distance = np.full(len(xyz_m), np.inf)
        if len(xyz_m) == 0:
            return distance, np.zeros(0, dtype=np.int64)
        facet = self.locate(xyz_m[:, :2], start=start)
        inside = facet >= 0
        points, under = xyz_m[inside], facet[inside]
        if not nearest_facet:
            corners = self.xyz_m[self.simplices[under]]                         # (q', 3, 3)
            normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
            normal /= np.linalg.norm(normal, axis=1, keepdims=True)
            distance[inside] = np.abs(np.einsum("qk,qk->q", points - corners[:, 0], normal))
            return distance, facet
        best = point_triangle_distance(points, self.xyz_m[self.simplices[under]])
        for side in range(3):
            other = self.neighbours[under, side]
            has = other >= 0
            d = point_triangle_distance(points[has], self.xyz_m[self.simplices[other[has]]])
            best[has] = np.minimum(best[has], d)
        distance[inside] = best
        return distance, facet

    def mirrored(self, xyz_m: np.ndarray, facet: np.ndarray, centre_ok: np.ndarray, *,
                 nearest_facet: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """`measure` of each point's mirror image in the nearest corner of the facet under it.

        Axelsson's (2000) mirror points: where the TIN cuts across a convex break line (a ridge,
        the upper edge of a terrace), the ground beyond its last vertex lies above the facet
        under it, while its image through that vertex, `2 v - p`, lies on the ground already in
        the TIN; an object's image lies as far below the ground as the object stands above it.

        Args:
          xyz_m: float64 `(q, 3)` points [m]. facet: int64 `(q,)` the facet under each (`measure`).
          centre_ok: bool `(k,)` over the vertices: those that may be the mirror's centre (the
            nearest such corner of the facet is taken; none: no image).

        Returns:
          `(distance, facet)` of the images as `measure` gives them: float64 `(q,)` [m], `inf`
          for an image outside the TIN or a point without one, and int64 `(q,)` (`-1`).
        """
        xyz_m = np.asarray(xyz_m, dtype=np.float64).reshape(-1, 3)
        distance = np.full(len(xyz_m), np.inf)
        image_facet = np.full(len(xyz_m), -1, dtype=np.int64)
        corners = self.simplices[np.maximum(facet, 0)]                          # (q, 3)
        gap = ((self.xyz_m[corners, :2] - xyz_m[:, None, :2]) ** 2).sum(axis=2)
        gap = np.where(centre_ok[corners], gap, np.inf)
        pick = np.argmin(gap, axis=1)
        has = (facet >= 0) & np.isfinite(gap[np.arange(len(xyz_m)), pick])
        centre = corners[has, pick[has]]
        image = 2.0 * self.xyz_m[centre] - xyz_m[has]
        distance[has], image_facet[has] = self.measure(image, nearest_facet=nearest_facet,
                                                       start=self.vertex_to_simplex[centre])
        return distance, image_facet

    def distance_m(self, xyz_m: np.ndarray, *, nearest_facet: bool = False) -> np.ndarray:
        """`measure`'s distance alone: float64 `(q,)` [m]."""
        return self.measure(xyz_m, nearest_facet=nearest_facet)[0]


def point_triangle_distance(points: np.ndarray, corners: np.ndarray) -> np.ndarray:
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
