"""Raster geometry: which cell a point falls in, and bilinear sampling between cell centres.

Convention (docs/ARCHITECTURE.md): a raster of shape `(h, w)` with square cells of `cell_m`
metres covers local `x in [0, w * cell_m)`, `y in [0, h * cell_m)`; **row 0 is the northern
edge** (max y):

    row = h - 1 - floor(y / cell_m),   col = floor(x / cell_m)

and the centre of cell `(row, col)` is at `x = (col + 0.5) * cell_m`,
`y = (h - 1 - row + 0.5) * cell_m`.
"""
from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import XY, Mask, Raster

__all__ = ["cell_index", "domain_mask", "replicate_edges", "sample_bilinear"]


def _check_cell_shape(cell_m: float, shape: tuple[int, int]) -> None:
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"shape must be (h, w) with h, w >= 1, got {shape}")


def cell_index(
    xy: XY, *, cell_m: float, shape: tuple[int, int]
) -> tuple[Int[Array, " n"], Int[Array, " n"], Bool[Array, " n"]]:
    """Row and column of the cell holding each point.

    Args:
      xy: local coordinates, shape `(n, 2)` [m], origin at the raster's south-west corner.
      cell_m: cell side [m] (static).
      shape: raster `(h, w)` (static).

    Returns:
      `(row, col, inside)`: int32 `(n,)` each and bool `(n,)`. `row = h - 1 - floor(y / cell_m)`
      (row 0 = north), `col = floor(x / cell_m)`. Outside points (and NaN coordinates) have
      `inside = False`; their row/col are clipped to `[-1, h]` x `[-1, w]`, so they never
      overflow but must not be used to index.
    """
    _check_cell_shape(cell_m, shape)
    h, w = shape
    fx = jnp.floor(xy[:, 0] / cell_m)
    fy = jnp.floor(xy[:, 1] / cell_m)
    inside = (fx >= 0) & (fx < w) & (fy >= 0) & (fy < h)       # False for NaN
    col = jnp.clip(jnp.nan_to_num(fx, nan=-1.0), -1, w).astype(jnp.int32)
    row = (h - 1) - jnp.clip(jnp.nan_to_num(fy, nan=h), -1, h).astype(jnp.int32)
    return row, col, inside


def sample_bilinear(z: Raster, xy: XY, *, cell_m: float) -> Float[Array, " n"]:
    """Bilinear interpolation of a raster between cell centres, clamped at the edges.

    Args:
      z: raster, shape `(h, w)`, row 0 = north; must be finite where sampled (inpaint first).
      xy: local coordinates, shape `(n, 2)` [m], origin at the raster's south-west corner.
      cell_m: cell side [m] (static).

    Returns:
      Values at the points, shape `(n,)`, dtype of `z`. A point at a cell centre gets that
      cell's value exactly; beyond the outermost centres (and outside the raster) the value
      of the nearest edge is continued (coordinates clamped to the centre lattice).

    Used to compare point heights with a DTM surface (SMRF, Pingel et al. 2013, Sec. 2.4).
    """
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    h, w = z.shape
    u = jnp.clip(xy[:, 0] / cell_m - 0.5, 0.0, w - 1.0)           # fractional column
    v = jnp.clip((h - 0.5) - xy[:, 1] / cell_m, 0.0, h - 1.0)     # fractional row (south = h-1)
    c0 = jnp.clip(jnp.floor(u).astype(jnp.int32), 0, max(w - 2, 0))
    r0 = jnp.clip(jnp.floor(v).astype(jnp.int32), 0, max(h - 2, 0))
    c1 = jnp.minimum(c0 + 1, w - 1)
    r1 = jnp.minimum(r0 + 1, h - 1)
    fu = (u - c0.astype(u.dtype)).astype(z.dtype)
    fv = (v - r0.astype(v.dtype)).astype(z.dtype)
    top = z[r0, c0] * (1 - fu) + z[r0, c1] * fu
    bottom = z[r1, c0] * (1 - fu) + z[r1, c1] * fu
    return top * (1 - fv) + bottom * fv


def domain_mask(hw: Int[Array, " 2"], shape: tuple[int, int]) -> Mask:
    """Cells of a `shape` raster inside a data extent `hw = (rows, cols)` anchored at the
    south-west corner (rows `h - hw[0] ..`, columns `.. hw[1] - 1`). bool `(h, w)`.

    The layout of a tile padded by `gfjax.tiling.batches` (row 0 = north); `hw` may be traced, so
    tiles of different extents share one compiled shape."""
    h, w = shape
    rows = jnp.arange(h, dtype=jnp.int32) >= h - hw[0]
    cols = jnp.arange(w, dtype=jnp.int32) < hw[1]
    return rows[:, None] & cols[None, :]


def replicate_edges(z: Raster, hw: Int[Array, " 2"]) -> Raster:
    """Copy the domain's northern row and eastern column over the padding, so that bilinear
    sampling near the domain edge clamps there as it would at the raster's own edge."""
    h, w = z.shape
    rows = jnp.maximum(jnp.arange(h, dtype=jnp.int32), h - hw[0])
    cols = jnp.minimum(jnp.arange(w, dtype=jnp.int32), jnp.maximum(hw[1] - 1, 0))
    return z[rows[:, None], cols[None, :]]
