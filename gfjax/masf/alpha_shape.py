"""The modified 3D alpha shape of Cao et al. (2024, Sec. 2.2, Algorithm 1), every layer at once.

A triangle sigma of the 3D Delaunay triangulation belongs to the layer of radius alpha when
(i) its circumradius rho <= alpha and (ii) one of the two spheres of radius alpha through its
vertices, centred at `c +- sqrt(alpha^2 - rho^2) * n` (c circumcentre, n unit normal), is
empty and its centre lies below the bottom TIN of the points (SPEC 4.2).

Fast form (SPEC 4, "faster forms"; Edelsbrunner & Muecke 1994): the centres of the empty
spheres through sigma's vertices are exactly the dual Voronoi edge, the segment of the line
`c + t n` between the circumcentres of sigma's one or two adjacent tetrahedra (a ray for a hull
triangle). `triangle_geometry` computes that `t` interval once per triangle (float64 numpy, on
the host); `layer_membership` (jit, float32) then decides every layer from the interval, with no
nearest-neighbour query per layer, and the "below" test is a bilinear lookup in the rasterised
bottom surface instead of a point location.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from gfjax.tiling.buckets import capacity_bucket

__all__ = ["TriangleGeometry", "triangle_geometry", "layer_membership", "layer_points"]

MIN_TRIANGLES = 1024     # the smallest triangle capacity of `layer_points`


class TriangleGeometry(NamedTuple):
    """Per-triangle quantities of the alpha test (float64 numpy on the host, float32 in jit).

    Attributes:
      centre_m: `(f, 3)` circumcentre c of the triangle [m].
      normal: `(f, 3)` unit normal n, oriented upwards (n_z >= 0).
      radius_m: `(f,)` circumradius rho [m]; `inf` for a degenerate (collinear) triangle.
      t_lo_m, t_hi_m: `(f,)` the empty-sphere centres are `c + t n` with `t_lo <= t <= t_hi`
        [m] (`-inf` / `inf` for a hull triangle's open side; `t_lo > t_hi`: no empty sphere).
    """

    centre_m: np.ndarray
    normal: np.ndarray
    radius_m: np.ndarray
    t_lo_m: np.ndarray
    t_hi_m: np.ndarray


def triangle_geometry(xyz_m: np.ndarray, faces: np.ndarray, opposite: np.ndarray) -> TriangleGeometry:
    """Circumcircle, normal and dual-Voronoi-edge interval of every triangle (float64).

    For a vertex d opposite the triangle, with `u = d - c`, `h = u . n`: d lies strictly inside
    the sphere centred at `c + t n` through the triangle iff `t * h > (|u|^2 - rho^2) / 2`.
    So d on the `+n` side bounds t from above by `(|u|^2 - rho^2) / (2 h)`, on the `-n` side
    from below; a d in the triangle's plane inside its circumcircle leaves no empty sphere, one
    outside or on it bounds nothing.

    Args:
      xyz_m: float64 `(p, 3)` local metres.
      faces: int64 `(f, 3)` triangle vertices. opposite: int64 `(f, 2)`, `-1` = none.
    """
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    a, b, c = (xyz_m[faces[:, i]] for i in range(3))
    e1, e2 = b - a, c - a
    cross = np.cross(e1, e2)
    cross_sq = np.einsum("fk,fk->f", cross, cross)
    degenerate = cross_sq <= 1e-18 * np.maximum(np.einsum("fk,fk->f", e1, e1), 1e-30) ** 2
    safe_sq = np.where(degenerate, 1.0, cross_sq)
    offset = (np.einsum("fk,fk->f", e1, e1)[:, None] * np.cross(e2, cross)
              + np.einsum("fk,fk->f", e2, e2)[:, None] * np.cross(cross, e1)) / (2.0 * safe_sq[:, None])
    centre = a + offset
    radius = np.where(degenerate, np.inf, np.linalg.norm(offset, axis=1))
    normal = cross / np.sqrt(safe_sq)[:, None]
    flip = (normal[:, 2] < 0) | ((normal[:, 2] == 0) & ((normal[:, 0] < 0) | ((normal[:, 0] == 0) & (normal[:, 1] < 0))))
    normal = np.where(flip[:, None], -normal, normal)
    t_lo = np.full(len(faces), -np.inf)
    t_hi = np.full(len(faces), np.inf)
    for column in range(opposite.shape[1]):
        has = opposite[:, column] >= 0
        u = xyz_m[np.where(has, opposite[:, column], 0)] - centre
        h = np.einsum("fk,fk->f", u, normal)
        q = np.einsum("fk,fk->f", u, u) - radius ** 2
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = q / (2.0 * h)
        upper = has & (h > 0)
        lower = has & (h < 0)
        t_hi = np.where(upper, np.minimum(t_hi, bound), t_hi)
        t_lo = np.where(lower, np.maximum(t_lo, bound), t_lo)
        blocked = has & (h == 0) & (q < 0)
        t_lo = np.where(blocked, np.inf, t_lo)
        t_hi = np.where(blocked, -np.inf, t_hi)
    return TriangleGeometry(centre, normal, radius, t_lo, t_hi)


def _sample_bilinear(z: Float[Array, "h w"], x: Float[Array, " f"], y: Float[Array, " f"],
                     cell_m: float) -> Float[Array, " f"]:
    """Bilinear between cell centres (row 0 = north), clamped at the raster edges."""
    h, w = z.shape
    fc = jnp.clip(x / cell_m - 0.5, 0.0, w - 1.0)
    fr = jnp.clip((h - 0.5) - y / cell_m, 0.0, h - 1.0)
    c0 = jnp.clip(jnp.floor(fc).astype(jnp.int32), 0, max(w - 2, 0))
    r0 = jnp.clip(jnp.floor(fr).astype(jnp.int32), 0, max(h - 2, 0))
    c1 = jnp.minimum(c0 + 1, w - 1)
    r1 = jnp.minimum(r0 + 1, h - 1)
    tc = fc - c0.astype(jnp.float32)
    tr = fr - r0.astype(jnp.float32)
    top = z[r0, c0] * (1.0 - tc) + z[r0, c1] * tc
    bottom = z[r1, c0] * (1.0 - tc) + z[r1, c1] * tc
    return top * (1.0 - tr) + bottom * tr


def _inside_at(inside: Bool[Array, "h w"], x: Float[Array, " f"], y: Float[Array, " f"],
               cell_m: float) -> Bool[Array, " f"]:
    h, w = inside.shape
    col = jnp.floor(x / cell_m).astype(jnp.int32)
    row = (h - 1) - jnp.floor(y / cell_m).astype(jnp.int32)
    ok = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    return ok & inside[jnp.clip(row, 0, h - 1), jnp.clip(col, 0, w - 1)]


@functools.partial(jax.jit, static_argnames=("cell_m",))
def layer_membership(geometry: TriangleGeometry, bottom_z_m: Float[Array, "h w"],
                     bottom_inside: Bool[Array, "h w"], alphas_m: Float[Array, " L"],
                     tol_m: Float[Array, ""], *, cell_m: float) -> Bool[Array, "L f"]:
    """Which triangles belong to each layer of the modified 3D alpha shape (Algorithm 1).

    Args:
      geometry: float32 `TriangleGeometry` (local metres; padding rows have `radius_m = inf`).
      bottom_z_m: `(h, w)` bottom surface at cell centres [m], filled everywhere.
      bottom_inside: `(h, w)` cells inside the x, y hull of the points; a sphere centre
        outside is never "below" (SPEC 4).
      alphas_m: `(L,)` layer radii [m]. tol_m: tolerance of the empty test along `t` [m].
      cell_m: raster cell [m] (static).

    Returns:
      bool `(L, f)`: triangle f is in layer l.
    """

    def one_layer(alpha):
        fits = geometry.radius_m <= alpha
        half = jnp.sqrt(jnp.maximum(alpha * alpha - geometry.radius_m * geometry.radius_m, 0.0))
        found = jnp.zeros(geometry.radius_m.shape, dtype=bool)
        for sign in (1.0, -1.0):
            t = sign * half
            centre = geometry.centre_m + t[:, None] * geometry.normal
            empty = (t >= geometry.t_lo_m - tol_m) & (t <= geometry.t_hi_m + tol_m)
            x, y = centre[:, 0], centre[:, 1]
            below = _inside_at(bottom_inside, x, y, cell_m) & (centre[:, 2] < _sample_bilinear(bottom_z_m, x, y, cell_m))
            found = found | (empty & below)
        return fits & found

    return jax.lax.map(one_layer, alphas_m)


def layer_points(xyz_m: np.ndarray, faces: np.ndarray, geometry: TriangleGeometry,
                 bottom_z_m: np.ndarray, bottom_inside: np.ndarray, alphas_m: np.ndarray, *,
                 cell_m: float, tol_m: float) -> np.ndarray:
    """Points of each layer: the vertices of its triangles (host wrapper of `layer_membership`).

    Triangles that can be in no layer (no empty sphere, or rho above the largest alpha) are
    dropped first; the rest are padded to a `capacity_bucket` of at least `MIN_TRIANGLES`
    (`2^k` or `1.5 * 2^k`) so few shapes compile; padding rows are in no layer.

    Returns:
      bool `(L, p)` numpy, point i is in layer l.
    """
    alphas_m = np.asarray(alphas_m, dtype=np.float64)
    layers = np.zeros((len(alphas_m), len(xyz_m)), dtype=bool)
    useful = (geometry.t_lo_m <= geometry.t_hi_m + tol_m) & (geometry.radius_m <= alphas_m.max())
    if not useful.any():
        return layers
    picked = np.flatnonzero(useful)
    capacity = capacity_bucket(len(picked), minimum=MIN_TRIANGLES)
    pad = capacity - len(picked)

    def padded(a: np.ndarray, fill: float) -> jnp.ndarray:
        a = a[picked].astype(np.float32)
        widths = [(0, pad)] + [(0, 0)] * (a.ndim - 1)
        return jnp.asarray(np.pad(a, widths, constant_values=fill))

    geometry32 = TriangleGeometry(padded(geometry.centre_m, 0.0), padded(geometry.normal, 0.0),
                                  padded(geometry.radius_m, np.inf), padded(geometry.t_lo_m, np.inf),
                                  padded(geometry.t_hi_m, -np.inf))
    member = layer_membership(geometry32, jnp.asarray(bottom_z_m, dtype=jnp.float32),
                              jnp.asarray(bottom_inside, dtype=bool),
                              jnp.asarray(alphas_m, dtype=jnp.float32),
                              jnp.asarray(tol_m, dtype=jnp.float32), cell_m=float(cell_m))
    member = np.asarray(member)[:, :len(picked)]
    for level in range(len(alphas_m)):
        layers[level, faces[picked[member[level]]].reshape(-1)] = True
    return layers
