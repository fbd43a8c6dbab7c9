"""Raster geometry: which cell a point falls in, and bilinear sampling between cell centres.

Convention (docs/ARCHITECTURE.md): a raster of shape `(h, w)` with square cells of `cell_m`
metres covers local `x in [0, w * cell_m)`, `y in [0, h * cell_m)`; **row 0 is the northern
edge** (max y):

    row = h - 1 - floor(y / cell_m),   col = floor(x / cell_m)

and the centre of cell `(row, col)` is at `x = (col + 0.5) * cell_m`,
`y = (h - 1 - row + 0.5) * cell_m`.
"""
from __future__ import annotations

import dataclasses

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import XY, Raster

__all__ = ["Grid", "cell_index", "sample_bilinear"]


def _check_cell_shape(cell_m: float, shape: tuple[int, int]) -> None:
    if not cell_m > 0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if len(shape) != 2 or min(shape) < 1:
        raise ValueError(f"shape must be (h, w) with h, w >= 1, got {shape}")


@dataclasses.dataclass(frozen=True)
class Grid:
    """A north-up raster geometry (static, hashable: usable as a `static_argnames` value).

    Attributes:
      origin_m: `(x0, y0)` of the raster's south-west corner in the caller's frame [m]. Local
        coordinates are `xy - origin_m`.
      cell_m: cell side [m].
      shape: `(h, w)` rows x columns; row 0 is the northern edge.
    """

    origin_m: tuple[float, float]
    cell_m: float
    shape: tuple[int, int]

    def __post_init__(self) -> None:
        _check_cell_shape(self.cell_m, self.shape)

    @classmethod
    def covering(cls, xy_min_m: tuple[float, float], xy_max_m: tuple[float, float], cell_m: float) -> Grid:
        """The smallest grid anchored at `xy_min_m` whose cells cover `[xy_min_m, xy_max_m]`.

        A point exactly on the max edge gets a cell of its own (one extra row/column), so every
        point of a bounding box is inside. Host-side (plain floats), call outside jit.
        """
        w = int(max(1, (xy_max_m[0] - xy_min_m[0]) // cell_m + 1))
        h = int(max(1, (xy_max_m[1] - xy_min_m[1]) // cell_m + 1))
        return cls((float(xy_min_m[0]), float(xy_min_m[1])), float(cell_m), (h, w))

    def local(self, xy: XY) -> XY:
        """Coordinates relative to the south-west corner, shape `(n, 2)` [m]."""
        origin = jnp.asarray(self.origin_m, dtype=xy.dtype)
        return xy - origin[None, :]

    def cell_index(self, xy: XY):
        """`cell_index` of `xy` given in the grid's frame (see the module function)."""
        return cell_index(self.local(xy), cell_m=self.cell_m, shape=self.shape)

    def centres(self) -> tuple[Raster, Raster]:
        """Cell-centre coordinates `(x, y)` in the grid's frame, each shape `(h, w)` [m]."""
        h, w = self.shape
        col = (jnp.arange(w, dtype=jnp.float32) + 0.5) * self.cell_m + self.origin_m[0]
        row_y = (h - 1 - jnp.arange(h, dtype=jnp.float32) + 0.5) * self.cell_m + self.origin_m[1]
        return jnp.broadcast_to(col[None, :], (h, w)), jnp.broadcast_to(row_y[:, None], (h, w))


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
