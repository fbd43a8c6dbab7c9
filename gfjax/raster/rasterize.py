"""Points -> per-cell statistics (min, max, mean, count, lowest point) with `jax.ops.segment_*`.

One pass of segment reductions over the points; a point contributes when it is `valid`, inside
the raster and has a finite z. Empty cells carry the reduction identities (`+inf` min, `-inf`
max, mean 0, count 0, argmin -1) and `valid = False`, never NaN.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Int

from gfjax._types import XY, Heights, Mask, PointMask, Raster
from gfjax.raster.grid import cell_index

__all__ = ["CellStats", "rasterize", "flat_cell"]


class CellStats(NamedTuple):
    """Per-cell statistics of the points in each cell, every field shape `(h, w)`.

    Attributes:
      z_min: lowest z [m]; `+inf` where empty.
      z_max: highest z [m]; `-inf` where empty.
      z_mean: mean z [m]; 0 where empty.
      count: number of points, int32.
      argmin: index (into the input arrays) of the lowest point, int32; among equal lowest
        z the smallest index; -1 where empty.
      valid: count > 0.
    """

    z_min: Raster
    z_max: Raster
    z_mean: Raster
    count: Int[Array, "h w"]
    argmin: Int[Array, "h w"]
    valid: Mask


def flat_cell(xy: XY, valid: PointMask, *, cell_m: float, shape: tuple[int, int]) -> Int[Array, " n"]:
    """Row-major flat cell id `row * w + col` of each point, int32 `(n,)`; `h * w` for points
    that are outside the raster or not `valid` (a dump segment callers drop)."""
    h, w = shape
    row, col, inside = cell_index(xy, cell_m=cell_m, shape=shape)
    return jnp.where(inside & valid, row * w + col, h * w)


def rasterize(xy: XY, z: Heights, valid: PointMask, *, cell_m: float, shape: tuple[int, int]) -> CellStats:
    """Bin points into a north-up raster and reduce z per cell.

    Args:
      xy: local coordinates, shape `(n, 2)` [m], origin at the raster's south-west corner.
      z: heights, shape `(n,)` [m]. Non-finite z are ignored.
      valid: points to use, bool `(n,)` (padding and ignored classes are False).
      cell_m: cell side [m] (static).
      shape: raster `(h, w)` (static).

    Returns:
      `CellStats`, each field `(h, w)`; row 0 = north (see `gfjax.raster.grid`).

    The minimum surface `ZImin` of SMRF (Pingel et al. 2013, Sec. 2.1) and PMF (Zhang et al.
    2003) is `z_min`; `argmin` names the point that made it.
    """
    h, w = shape
    n = z.shape[0]
    if xy.shape != (n, 2) or valid.shape != (n,):
        raise ValueError(f"rasterize: need xy (n, 2), z (n,), valid (n,); got {xy.shape}, {z.shape}, {valid.shape}")
    use = valid & jnp.isfinite(z)
    cell = flat_cell(xy, use, cell_m=cell_m, shape=shape)
    segments = h * w + 1                                       # the last one collects the rest
    z_min = jax.ops.segment_min(z, cell, num_segments=segments)
    z_max = jax.ops.segment_max(z, cell, num_segments=segments)
    z_sum = jax.ops.segment_sum(jnp.where(use, z, 0), cell, num_segments=segments)
    count = jax.ops.segment_sum(jnp.ones(n, jnp.int32), cell, num_segments=segments)
    is_lowest = use & (z == z_min[cell])
    index = jnp.where(is_lowest, jnp.arange(n, dtype=jnp.int32), n)
    argmin = jax.ops.segment_min(index, cell, num_segments=segments)

    count = count[:-1].reshape(h, w)
    filled = count > 0
    z_mean = jnp.where(filled, z_sum[:-1].reshape(h, w) / jnp.maximum(count, 1).astype(z.dtype), 0)
    return CellStats(
        z_min=jnp.where(filled, z_min[:-1].reshape(h, w), jnp.inf).astype(z.dtype),
        z_max=jnp.where(filled, z_max[:-1].reshape(h, w), -jnp.inf).astype(z.dtype),
        z_mean=z_mean.astype(z.dtype),
        count=count,
        argmin=jnp.where(filled, argmin[:-1].reshape(h, w), -1),
        valid=filled,
    )
