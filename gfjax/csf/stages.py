"""CSF stages around the cloth simulation (Zhang et al. 2016; `cloth-simulation-filter`).

All in the package's inverted frame (`u = -z`, metres) on the particle grid `[j, i]` (row 0 =
SOUTH; `gfjax.csf.cloth`). A cloud's grid, as in CSF.cpp `do_cloth`: the particle `(j, i)` sits
at `(x0 + i c, y0 + j c)` with `(x0, y0)` = bounding-box minimum minus 2 cells, and the grid has
`floor(extent / c) + 4` particles along each axis. Tiles are padded to a common static shape;
`exists` marks the particles of the tile's own grid.

Stages:
- `grid_size`: particles along x and y (host and traced forms agree: same float32 formula).
- `particle_heights`: Rasterization.cpp `RasterTerrian`: each point goes to its nearest
  particle (rounding), each particle keeps the `u` of its nearest point; empty particles take
  the first non-empty one scanning right, left, south, north along their row and column.
- `smooth_slopes`: Cloth.cpp `movableFilter` (the `bSloopSmooth` post-processing).
- `height_above_cloth`, `is_ground`: c2cdist.cpp: bilinear cloth height at each point and the
  class threshold test.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import XY, Heights, Mask, PointMask, Raster
from gfjax.csf.config import BUFFER_PX, MIN_SMOOTH_COMPONENT, SMOOTH_THRESHOLD_M
from gfjax.raster import label_components

__all__ = ["grid_size", "particle_heights", "scanline_fill", "smooth_slopes", "height_above_cloth",
           "is_ground"]

_NEIGHBOURS_4 = ((0, -1), (0, 1), (-1, 0), (1, 0))


def grid_size(extent_m: Float[Array, " 2"], *, cell_m: float) -> Int[Array, " 2"]:
    """Particles along x and y: `floor(extent / cell) + 4` (CSF.cpp `width_num`, `height_num`).

    Args:
      extent_m: bounding-box side along x and y, float32 `(2,)` [m].
    Returns:
      int32 `(2,)`: `(w, h)`.
    """
    return (jnp.floor(extent_m / jnp.float32(cell_m)) + 2 * BUFFER_PX).astype(jnp.int32)


def particle_heights(xy: XY, u: Heights, valid: PointMask, *, cell_m: float,
                     shape: tuple[int, int]) -> tuple[Raster, Mask]:
    """Inverted height of the nearest point for each particle, before gap filling.

    Args:
      xy: point positions relative to the cloth origin (bounding-box minimum - 2 cells), `(n, 2)`
        [m]; all >= 2 cells for valid points.
      u: inverted heights `-z`, `(n,)` [m].
      valid: points that take part, bool `(n,)`.
      cell_m: particle spacing (static).
      shape: static grid shape `(h, w)`.

    Returns:
      `(heights, has_point)`: `(h, w)` [m] (`-inf` where no point) and bool `(h, w)`.
      A particle takes the point nearest to it in xy among the points that round to it; on an
      exact tie the lowest point (largest `u`) wins, so the result does not depend on point order
      (the package keeps the first one in file order).
    """
    h, w = shape
    grid = xy / jnp.float32(cell_m)
    col = jnp.floor(grid[:, 0] + 0.5).astype(jnp.int32)
    row = jnp.floor(grid[:, 1] + 0.5).astype(jnp.int32)
    inside = valid & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    flat = jnp.where(inside, row * w + col, h * w)               # dump slot h * w
    d_xy = xy - jnp.stack([col, row], axis=1).astype(xy.dtype) * jnp.float32(cell_m)
    dist2 = jnp.sum(d_xy * d_xy, axis=1)
    inf = jnp.asarray(jnp.inf, xy.dtype)
    best = jax.ops.segment_min(jnp.where(inside, dist2, inf), flat, num_segments=h * w + 1)
    nearest = inside & (dist2 == best[flat])
    heights = jax.ops.segment_max(jnp.where(nearest, u, -inf), flat, num_segments=h * w + 1)
    heights = heights[: h * w].reshape(h, w)
    return heights, heights > -inf


def _scan_axis(z: Raster, ok: Mask, axis: int, forward: bool) -> tuple[Raster, Mask]:
    """Value of the first `ok` cell strictly after (forward) or before each cell along `axis`."""
    n = z.shape[axis]
    index = lax.broadcasted_iota(jnp.int32, z.shape, axis)
    if forward:
        nxt = lax.cummin(jnp.where(ok, index, n), axis=axis, reverse=True)
        nxt = jnp.concatenate([lax.slice_in_dim(nxt, 1, n, axis=axis),
                               jnp.full_like(lax.slice_in_dim(nxt, 0, 1, axis=axis), n)], axis=axis)
        found = nxt < n
    else:
        nxt = lax.cummax(jnp.where(ok, index, -1), axis=axis)
        nxt = jnp.concatenate([jnp.full_like(lax.slice_in_dim(nxt, 0, 1, axis=axis), -1),
                               lax.slice_in_dim(nxt, 0, n - 1, axis=axis)], axis=axis)
        found = nxt >= 0
    value = jnp.take_along_axis(z, jnp.clip(nxt, 0, n - 1), axis=axis)
    return value, found


def scanline_fill(heights: Raster, has_point: Mask) -> Raster:
    """Fill empty particles as Rasterization.cpp `findHeightValByScanline`.

    Order: own point; else the first particle with a point to the east (+i), to the west, to
    the south (-j), to the north, along the particle's own row and column. Particles whose row
    and column are both empty (the corners of the 2-cell buffer) go to the package's
    breadth-first neighbour search; here they take the same scan over the filled grid, which
    picks the same particle whenever the nearest diagonal one holds a point.

    Args:
      heights: `(h, w)` [m], meaningful where `has_point`.
      has_point: bool `(h, w)`.
    Returns:
      Filled heights `(h, w)` [m] (finite wherever the grid holds any point).
    """
    def one_pass(z: Raster, ok: Mask) -> tuple[Raster, Mask]:
        out, done = z, ok
        for axis, forward in ((1, True), (1, False), (0, False), (0, True)):
            value, found = _scan_axis(z, ok, axis, forward)
            take = ~done & found
            out = jnp.where(take, value, out)
            done = done | take
        return out, done

    filled, done = one_pass(heights, has_point)
    filled2, _ = one_pass(filled, done)
    return jnp.where(done, filled, filled2)


def _shift4(x: Array, dj: int, di: int, fill) -> Array:
    h, w = x.shape
    xp = jnp.pad(x, 1, constant_values=fill)
    return lax.slice(xp, (1 + dj, 1 + di), (1 + dj + h, 1 + di + w))


def smooth_slopes(u: Raster, movable: Mask, exists: Mask, heights: Raster) -> tuple[Raster, Mask]:
    """Slope smoothing, Cloth.cpp `movableFilter` (`bSloopSmooth`).

    In every 4-connected component of movable particles with more than 50 particles, a
    particle is put on the surface and fixed when a chain of 4-neighbours links it to an
    already fixed particle with `|h(p) - h(q)| < 0.3 m` at each link (the package's
    `findUnmovablePoint` seeds and `handle_slop_connected` breadth-first growth; their
    `< 9999 m` height test is always true and is left out).

    Args:
      u, heights: cloth and surface `(h, w)` [m]; movable, exists: bool `(h, w)`.
    Returns:
      `(u, movable)` after smoothing.
    """
    here = movable & exists              # particles of a padded grid's margin join no component
    labels, _ = label_components(here, connectivity=4)
    size = jax.ops.segment_sum(jnp.ones(labels.size, jnp.int32), labels.reshape(-1),
                               num_segments=labels.size + 1)
    big = here & (size[labels] > MIN_SMOOTH_COMPONENT)
    fixed = exists & ~movable
    links = [(dj, di, jnp.abs(heights - _shift4(heights, dj, di, jnp.inf)) < SMOOTH_THRESHOLD_M)
             for dj, di in _NEIGHBOURS_4]

    def grow(state: tuple[Mask, Bool[Array, ""]]) -> tuple[Mask, Bool[Array, ""]]:
        reached, _ = state
        source = fixed | reached
        new = reached
        for dj, di, close in links:
            new = new | (big & close & _shift4(source, dj, di, False))
        return new, jnp.any(new != reached)

    reached, _ = lax.while_loop(lambda s: s[1], grow, (jnp.zeros_like(movable), jnp.array(True)))
    return jnp.where(reached, heights, u), movable & ~reached


def height_above_cloth(xy: XY, u: Heights, cloth_u: Raster, *, cell_m: float) -> Heights:
    """Signed gap `cloth(x, y) - u` at each point, bilinear in the cloth (c2cdist.cpp).

    Args:
      xy: positions relative to the cloth origin `(n, 2)` [m] (>= 2 cells for cloud points).
      u: inverted point heights `(n,)` [m]; cloth_u: `(h, w)` [m], `[j, i]` with row 0 south.
    Returns:
      `(n,)` [m]; in the upright frame, the point's height above the cloth.
    """
    h, w = cloth_u.shape
    grid = xy / jnp.float32(cell_m)
    col = jnp.clip(jnp.floor(grid[:, 0]).astype(jnp.int32), 0, w - 2)
    row = jnp.clip(jnp.floor(grid[:, 1]).astype(jnp.int32), 0, h - 2)
    fx = grid[:, 0] - col.astype(grid.dtype)
    fy = grid[:, 1] - row.astype(grid.dtype)
    c00, c01 = cloth_u[row, col], cloth_u[row, col + 1]
    c10, c11 = cloth_u[row + 1, col], cloth_u[row + 1, col + 1]
    cloth = c00 * (1 - fx) * (1 - fy) + c10 * (1 - fx) * fy + c11 * fx * fy + c01 * fx * (1 - fy)
    return cloth - u


def is_ground(height_m: Heights, class_threshold_m: Float[Array, ""]) -> PointMask:
    """The class test `|height| < class_threshold` (c2cdist.cpp); the one hard threshold."""
    return jnp.abs(height_m) < class_threshold_m
