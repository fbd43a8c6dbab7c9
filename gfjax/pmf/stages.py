"""PMF raster stages for one tile, pure JAX (Zhang, Chen, Whitman, Shyu, Yan & Zhang 2003).

Zhang et al. (2003), "A progressive morphological filter for removing nonground measurements
from airborne LIDAR data", IEEE TGRS 41(4):872-882, Sec. II-III, as PDAL's `filters.pmf` runs
it: the minimum surface is opened with square windows of growing size `w_k` (Eq. 4-5), each
opening applied to the previous opened surface; a point whose height above the k-th opened
surface is not below `dh_k` (Eq. 7, capped at `dh_max`) is non-ground, for good.

Every function takes one tile (no batch axis) and is correct under `jax.vmap`. A tile raster of
static shape `(h, w)` may be padded beyond the tile's own extent `hw = (h_data, w_data)` (traced
int32): the data occupy the south-west corner (row 0 = north), the `domain`; the openings
ignore cells outside it, exactly as if the raster ended at the domain's edge. The one threshold
test is isolated in `is_ground_point` so that `gfjax.tune` can relax it.
"""
from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from gfjax._types import Heights, Mask, PointMask, Points, Raster
from gfjax.pmf.config import Config, Params
from gfjax.raster.fill import inpaint_nearest
from gfjax.raster.grid import cell_index, domain_mask
from gfjax.raster.morphology import opening
from gfjax.raster.rasterize import rasterize

__all__ = ["TileDiagnostics", "thresholds_m", "is_ground_point", "minimum_surface", "rasterize_min", "fill_minimum",
           "progressive_openings", "surfaces", "classify_points"]


class TileDiagnostics(NamedTuple):
    """Intermediate rasters of one tile, `(h, w)` each (row 0 = north), for plots.

    Attributes:
      zimin: lowest z per cell, empty cells filled from the nearest non-empty cell [m].
      empty: cells that held no point.
      surface: the last (largest-window) opened surface [m].
      domain: cells inside the tile's own extent (False on padding).
    """

    zimin: Raster
    empty: Mask
    surface: Raster
    domain: Mask


def thresholds_m(params: Params, *, windows_px: tuple[int, ...], cell_m: float) -> Float[Array, " k"]:
    """Elevation-difference thresholds `dh_k` [m], one per window (Zhang et al. 2003, Eq. 7):
    `dh_0 = dh0`, `dh_k = slope (w_k - w_{k-1}) c + dh0`, all capped at `dh_max`."""
    sizes = jnp.asarray(windows_px, jnp.float32)
    growth = jnp.concatenate([jnp.zeros(1, jnp.float32), sizes[1:] - sizes[:-1]])
    dh = params.slope * growth * jnp.float32(cell_m) + params.initial_distance_m
    return jnp.minimum(dh, params.max_distance_m)


def is_ground_point(dz_m: Heights, threshold_m: Float[Array, ""]) -> PointMask:
    """PMF's test at one window: a point stays ground while its height above the opened
    surface is below the threshold (PDAL: `z - opened < dh_k`). bool `(n,)`."""
    return dz_m < threshold_m


def minimum_surface(xyz: Points, valid: PointMask, domain: Mask, *, cell_m: float,
                    shape: tuple[int, int]) -> tuple[Raster, Mask]:
    """Lowest z per cell, empty cells of the domain filled from the nearest non-empty cell
    (PDAL fills them from the nearest points). Returns `(zimin, filled)`, `(h, w)` each."""
    return fill_minimum(*rasterize_min(xyz, valid, cell_m=cell_m, shape=shape), domain)


def rasterize_min(xyz: Points, valid: PointMask, *, cell_m: float, shape: tuple[int, int]) -> tuple[Raster, Mask]:
    """Lowest z per cell and the cells holding a point, `(h, w)` each."""
    cells = rasterize(xyz[:, :2], xyz[:, 2], valid, cell_m=cell_m, shape=shape)
    return cells.z_min, cells.valid


def fill_minimum(z_min: Raster, filled: Mask, domain: Mask) -> tuple[Raster, Mask]:
    """`minimum_surface` from the rasterized minimum: `(zimin, filled)`, `(h, w)` each."""
    filled = filled & domain
    return inpaint_nearest(z_min, filled), filled


def progressive_openings(zimin: Raster, domain: Mask, *, windows_px: tuple[int, ...]) -> Float[Array, "k h w"]:
    """The opened surfaces, one per window (Zhang et al. 2003, Sec. II-B): the k-th is the
    opening (erosion then dilation, square window of `w_k` cells, radius `(w_k - 1) / 2`) of the
    (k-1)-th; cells outside the domain are ignored and keep their value. `(k, h, w)` [m]."""
    surfaces = []
    surface = zimin
    for size in windows_px:
        opened = opening(surface, domain, radius_px=(size - 1) // 2, footprint="square")
        surface = jnp.where(domain, opened, surface)
        surfaces.append(surface)
    return jnp.stack(surfaces)


def classify_points(xyz: Points, valid: PointMask, opened: Float[Array, "k h w"], params: Params, *,
                    config: Config) -> PointMask:
    """A point is ground when it passes every window's test against the opened surface of its
    own cell. bool `(n,)`, False where `~valid`."""
    _, h, w = opened.shape
    row, col, inside = cell_index(xyz[:, :2], cell_m=config.cell_m, shape=(h, w))
    dh = thresholds_m(params, windows_px=config.windows_px, cell_m=config.cell_m)
    ground = valid & inside
    for k in range(opened.shape[0]):
        ground = ground & is_ground_point(xyz[:, 2] - opened[k, row, col], dh[k])
    return ground


def surfaces(z_min: Raster, filled: Mask, hw: Int[Array, " 2"], *, config: Config) -> tuple[Float[Array, "k h w"], TileDiagnostics]:
    """The raster part of a tile: ZImin filled, then the progressive openings. Returns the
    opened stack `(k, h, w)` and the tile's `TileDiagnostics`."""
    domain = domain_mask(hw, z_min.shape)
    zimin, filled = fill_minimum(z_min, filled, domain)
    opened = progressive_openings(zimin, domain, windows_px=config.windows_px)
    return opened, TileDiagnostics(zimin=zimin, empty=domain & ~filled, surface=opened[-1], domain=domain)
