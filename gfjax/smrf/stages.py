"""SMRF raster stages for one tile, pure JAX (Pingel, Clarke & McBride 2013).

Every function takes one tile (no batch axis) and is correct under `jax.vmap`. A tile raster
of static shape `(h, w)` may be padded beyond the tile's own extent `hw = (h_data, w_data)`
(a traced int32 pair, so tiles of different extents share one compiled shape): the data
occupy the south-west corner, rows `h - h_data .. h - 1` and columns `0 .. w_data - 1`
(row 0 = north, docs/ARCHITECTURE.md). That corner is the `domain`: the openings ignore cells
outside it and the slope uses one-sided differences at its edge, exactly as if the raster
ended there; bilinear sampling sees the domain's edge values continued over the padding; the
harmonic fills solve the Laplace equation on the domain alone (zero flux across its edge). So
the labels of a tile do not depend on the shape bucket it is padded to (tests/smrf).

The thresholds are isolated in `is_object` and `is_ground_point`, so `gfjax.tune` can swap
them for relaxed (sigmoid) versions.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float, Int

from gfjax._types import Heights, Mask, PointMask, Points, Raster
from gfjax.raster.fill import inpaint_harmonic, inpaint_nearest
from gfjax.raster.grid import domain_mask, replicate_edges, sample_bilinear
from gfjax.raster.morphology import opening
from gfjax.raster.rasterize import rasterize
from gfjax.smrf.config import Config, Params

__all__ = [
    "TileDiagnostics", "is_object", "is_ground_point", "next_opening", "progressive_filter", "low_outliers", "inpaint",
    "gradient_magnitude", "rasterize_min", "surfaces", "classify_points",
]


class TileDiagnostics(NamedTuple):
    """Intermediate rasters of one tile, each `(h, w)` (row 0 = north), for plots.

    Attributes:
      zimin: minimum z per cell, empty cells inpainted [m] (Sec. 2.1, "ZImin").
      empty: cells that held no point.
      low_outliers: cells marked by the low-outlier filter on -ZImin (Sec. 2.1).
      object_cells: cells the progressive opening marked as objects (Sec. 2.2).
      zipro: provisional ground surface, ZImin without empty, low-outlier and object cells,
        inpainted [m] (Sec. 2.3, "ZIpro").
      slope: gradient magnitude of ZIpro, rise over run [-] (Sec. 2.4).
      domain: cells inside the tile's own extent (False on padding).
    """

    zimin: Raster
    empty: Mask
    low_outliers: Mask
    object_cells: Mask
    zipro: Raster
    slope: Raster
    domain: Mask


def is_object(surface: Raster, opened: Raster, threshold_m: Float[Array, ""]) -> Mask:
    """The progressive filter's test: a cell is an object when the opening lowered it by more
    than `threshold_m` (= slope * r * cell, Pingel et al. 2013, Eq. 2). bool `(h, w)`."""
    return (surface - opened) > threshold_m


def is_ground_point(dz_m: Heights, slope: Heights, params: Params) -> PointMask:
    """The final point test (Sec. 2.4): ground iff `|z - ZIpro| <= threshold + scalar * slope`.

    Args:
      dz_m: point height minus ZIpro at the point (bilinear), shape `(n,)` [m].
      slope: local ZIpro slope at the point, rise over run, shape `(n,)`.
    """
    return jnp.abs(dz_m) <= params.threshold_m + params.scalar * slope


def next_opening(surface: Raster, domain: Mask, radius_px: Int[Array, ""], *, max_radius_px: int) -> Raster:
    """The progressive filter's step r (Sec. 2.2): `surface` opened by the disk of radius
    `radius_px` cells (traced, `<= max_radius_px`) over the domain; cells off the domain keep
    their height. `(h, w)` [m]."""
    opened = opening(surface, domain, radius_px=radius_px, footprint="disk", max_radius_px=max_radius_px)
    return jnp.where(domain, opened, surface)


def progressive_filter(surface: Raster, domain: Mask, slope: Float[Array, ""], *,
                       cell_m: float, max_radius_px: int) -> Mask:
    """Pingel et al. (2013, Sec. 2.2): open the surface with disks of radius r = 1..max_radius_px
    cells, each opening applied to the previous opened surface (incremental); a cell whose
    height drops by more than `slope * r * cell_m` at step r is an object.

    Args:
      surface: a gap-free surface `(h, w)` [m] (ZImin, or -ZImin for low outliers).
      domain: cells of the tile; others are ignored by the opening and never objects.
      slope: tolerated slope, rise over run (traced).
      cell_m, max_radius_px: static.

    Returns:
      Object cells, bool `(h, w)`.
    """
    cell = jnp.asarray(cell_m, surface.dtype)

    def step(radius_px, carry):             # one loop body for every radius: a small program
        surface, objects = carry
        opened = next_opening(surface, domain, radius_px, max_radius_px=max_radius_px)
        threshold_m = slope * radius_px.astype(surface.dtype) * cell
        return opened, objects | (domain & is_object(surface, opened, threshold_m))

    objects = jnp.zeros(surface.shape, dtype=jnp.bool_)
    return lax.fori_loop(1, max_radius_px + 1, step, (surface, objects))[1]


def low_outliers(zimin: Raster, domain: Mask, *, config: Config) -> Mask:
    """Low-outlier cells (Sec. 2.1): the progressive filter applied to -ZImin with slope
    `config.low_outlier_slope` and a window of `config.low_outlier_radius_px` cells, i.e. cells
    more than `slope * r * cell` below the opening of the inverted surface. bool `(h, w)`."""
    slope = jnp.asarray(config.low_outlier_slope, zimin.dtype)
    return progressive_filter(-zimin, domain, slope, cell_m=config.cell_m,
                              max_radius_px=config.low_outlier_radius_px)


def inpaint(z: Raster, known: Mask, *, config: Config, domain: Mask | None = None) -> Raster:
    """Fill the cells `~known` from the known ones (Sec. 2.1/2.3): harmonic (Laplace) fill or
    nearest known cell, per `config.inpaint`. Returns a finite `(h, w)` raster [m] (zeros when
    nothing is known).

    `domain`: the tile's cells (None = the whole raster); `known` should lie inside it. The
    harmonic fill is solved on the domain alone (zero flux across its edge; 0 outside), so
    padding never moves it; the nearest known cell is independent of padding anyway."""
    z = jnp.where(known, z, 0.0).astype(z.dtype)
    if config.inpaint == "nearest":
        filled = inpaint_nearest(z, known)
    else:
        filled = inpaint_harmonic(z, known, domain=domain, max_iter=config.inpaint_max_iter,
                                  tol_m=config.inpaint_tol_m)
    return jnp.where(jnp.any(known), filled, jnp.zeros_like(z))


def gradient_magnitude(z: Raster, domain: Mask, *, cell_m: float) -> Raster:
    """Slope of a surface, `sqrt(dz/dx^2 + dz/dy^2)` (rise over run), per cell `(h, w)`.

    Central differences inside the domain and one-sided differences at its edges, as
    `numpy.gradient(z, cell_m)` on the domain alone; 0 along an axis of one cell.
    """
    def axis_derivative(axis: int) -> Raster:
        zp = jnp.pad(z, [(1, 1) if a == axis else (0, 0) for a in range(2)], mode="edge")
        dp = jnp.pad(domain, [(1, 1) if a == axis else (0, 0) for a in range(2)])
        n = z.shape[axis]
        lo = jax.lax.slice_in_dim(zp, 0, n, axis=axis)
        hi = jax.lax.slice_in_dim(zp, 2, n + 2, axis=axis)
        lo_in = jax.lax.slice_in_dim(dp, 0, n, axis=axis)
        hi_in = jax.lax.slice_in_dim(dp, 2, n + 2, axis=axis)
        lo = jnp.where(lo_in, lo, z)
        hi = jnp.where(hi_in, hi, z)
        run = (lo_in.astype(z.dtype) + hi_in.astype(z.dtype)) * jnp.asarray(cell_m, z.dtype)
        return jnp.where(run > 0, (hi - lo) / jnp.where(run > 0, run, 1), 0)

    gy, gx = axis_derivative(0), axis_derivative(1)
    return jnp.sqrt(gx * gx + gy * gy)


def rasterize_min(xyz: Points, valid: PointMask, *, cell_m: float, shape: tuple[int, int]) -> tuple[Raster, Mask]:
    """Lowest z per cell and the cells holding a point (Sec. 2.1), `(h, w)` each."""
    cells = rasterize(xyz[:, :2], xyz[:, 2], valid, cell_m=cell_m, shape=shape)
    return cells.z_min, cells.valid


def surfaces(z_min: Raster, filled: Mask, hw: Int[Array, 2], params: Params, *, config: Config) -> TileDiagnostics:
    """The raster part of SMRF (Sec. 2.1-2.3) on one tile: ZImin, low outliers, the progressive
    opening, ZIpro and its slope.

    Args:
      z_min: lowest z per cell `(h, w)` [m] (any value where `~filled`).
      filled: cells holding at least one point.
      hw: int32 `(2,)` the tile's own extent inside the raster (see `domain_mask`).
      params: traced thresholds (only `slope` is used here).
      config: static settings.
    """
    domain = domain_mask(hw, z_min.shape)
    filled = filled & domain
    # 1. ZImin: lowest point per cell, empty cells inpainted.
    zimin = inpaint(z_min, filled, config=config, domain=domain)
    # 2. Low outliers: progressive filter on -ZImin, slope 5, one-cell window.
    low = low_outliers(zimin, domain, config=config)
    # 3. Progressive opening r = 1..ceil(window / cell) with threshold slope * r * cell.
    objects = progressive_filter(zimin, domain, params.slope, cell_m=config.cell_m,
                                 max_radius_px=config.max_radius_px)
    # 4. ZIpro: ZImin without empty, low-outlier and object cells, inpainted.
    zipro = inpaint(zimin, filled & ~low & ~objects, config=config, domain=domain)
    slope = gradient_magnitude(zipro, domain, cell_m=config.cell_m)
    return TileDiagnostics(zimin=zimin, empty=domain & ~filled, low_outliers=low, object_cells=objects,
                       zipro=zipro, slope=slope, domain=domain)


def classify_points(xyz: Points, valid: PointMask, zipro: Raster, slope: Raster, hw: Int[Array, 2],
                    params: Params, *, cell_m: float) -> PointMask:
    """Sec. 2.4: a point is ground when `|z - ZIpro(x, y)| <= threshold + scalar * slope(x, y)`,
    both rasters sampled bilinearly between cell centres. bool `(n,)`, False where `~valid`."""
    surface_at = sample_bilinear(replicate_edges(zipro, hw), xyz[:, :2], cell_m=cell_m)
    slope_at = sample_bilinear(replicate_edges(slope, hw), xyz[:, :2], cell_m=cell_m)
    return valid & is_ground_point(xyz[:, 2] - surface_at, slope_at, params)
