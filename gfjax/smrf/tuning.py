"""SMRF with relaxed thresholds, composed from `gfjax.smrf.stages` (Pingel et al. 2013).

The tuned parameters act at two tests (SPEC section 7):

* `slope` at the progressive filter's object test (Sec. 2.2, Eq. 2): a cell is an object when
  some opening `r` lowers it by more than `slope * r * cell`. The openings themselves do not
  depend on any tuned parameter, so `prepare_tile` computes the surface sequence once per
  tile (`surfaces[0]` = ZImin, `surfaces[r]` = its r-th incremental opening, with
  `stages.next_opening`, the step of `stages.progressive_filter`); each step
  then only re-tests the drops. The relaxed object weight is
  `o = sigmoid(max_r(drop_r - slope * r * cell) / T)` (`relax.soft_or_max`).
* `threshold_m` and `scalar` at the final point test (Sec. 2.4): the relaxed ground
  weight is `sigmoid((threshold + scalar * slope_local - |z - ZIpro|) / T)`.

The object mask reaches the point test only through the inpainting of ZIpro (Sec. 2.3). For
`slope` to get a gradient the relaxed mask enters ZIpro as a soft weight: with the keep
weight `k = (1 - o)` on filled, non-low-outlier cells (0 elsewhere), ZIpro solves
`u = k * ZImin + (1 - k) * mean_4(u)`, a soft-Dirichlet harmonic fill that is exactly the
harmonic fill of the plain filter when `k` is 0/1. It is computed as `sweeps` Jacobi sweeps
started from the hard harmonic fill of the cells with `k > 1/2` (`stages.inpaint`, no
gradient through the start): the gradient is the truncated Neumann series of the implicit
one, local to `sweeps` cells. The local slope raster is taken on the stopped-gradient ZIpro
(its square root has no derivative on flat cells); `scalar` gets its gradient through it.

With `temperature=None` every test is the plain filter's own (`stages.is_object`,
`stages.is_ground_point`) and ZIpro is `stages.inpaint`: the labels equal
`gfjax.smrf.programs.classify_tile` bit for bit (tested).

`window_m` sets the number of openings: it is not differentiable (no gradient reaches it) and
is chosen from a small grid; `prepare_tile` computes the openings up to the largest window
once, and `ground_weight` takes the window's radius as a traced integer (one compile).
"""
from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Float, Int

from gfjax._types import Mask, PointMask, Points, Raster
from gfjax.raster.grid import domain_mask, replicate_edges, sample_bilinear
from gfjax.raster.rasterize import rasterize
from gfjax.smrf import stages
from gfjax.smrf.config import Config, Params
from gfjax.tune import relax
from gfjax.tune.params import bound
from gfjax.tune.tuners import GradientTuner

__all__ = ["TUNER", "BOUNDS", "GRID", "UNITS", "Prepared", "prepare_tile", "ground_weight", "make_params",
           "soft_inpaint", "radius_for"]

# Tuned scalars with PDAL's defaults and the bounds the optimiser keeps them in; a 5-value
# grid over each (`numpy.linspace(lo, hi, 5)`, the grid search of the experiments) holds the
# defaults.
BOUNDS = (
    bound(Params, "slope", 0.05, 0.45, "1 (rise over run)"),
    bound(Params, "threshold_m", 0.1, 0.9, "m"),
    bound(Params, "scalar", 0.0, 2.5, "m per unit slope"),
)
# Static parameters searched on a grid (each value: its own relaxed fit).
GRID = {"window_m": (12.0, 18.0, 24.0)}
UNITS = {b.name: b.unit for b in BOUNDS} | {"window_m": "m"}
SOFT_SWEEPS = 24


class Prepared(NamedTuple):
    """One tile's parameter-free SMRF rasters (Sec. 2.1-2.2), shape `(h, w)` unless noted.

    Attributes:
      surfaces: float32 `(R + 1, h, w)`: ZImin, then its incremental openings r = 1..R [m].
      domain: cells of the tile (False on padding).
      candidate: filled cells that are not low outliers (ZIpro may keep them).
      xyz: float32 `(n, 3)` tile-local points [m]; valid: bool `(n,)`; hw: int32 `(2,)`.
    """

    surfaces: Float[Array, "r h w"]
    domain: Mask
    candidate: Mask
    xyz: Points
    valid: PointMask
    hw: Int[Array, 2]


def make_params(values: Float[Array, " 3"]) -> Params:
    """SMRF `Params` from a vector ordered as `BOUNDS` (traced values kept as they are)."""
    return Params(slope=values[0], threshold_m=values[1], scalar=values[2])


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def prepare_tile(xyz: Points, valid: PointMask, hw: Int[Array, 2], *, config: Config,
                 shape: tuple[int, int]) -> Prepared:
    """ZImin, low outliers and the opening sequence of one tile, as `gfjax.smrf.programs.classify_tile`
    computes them (steps 1-3 without the object test), up to `config.max_radius_px`."""
    domain = domain_mask(hw, shape)
    cells = rasterize(xyz[:, :2], xyz[:, 2], valid, cell_m=config.cell_m, shape=shape)
    filled = cells.valid & domain
    zimin = stages.inpaint(cells.z_min, filled, config=config, domain=domain)
    low = stages.low_outliers(zimin, domain, config=config)
    def step(surface, radius_px):                           # as stages.progressive_filter
        opened = stages.next_opening(surface, domain, radius_px, max_radius_px=config.max_radius_px)
        return opened, opened

    radii = jnp.arange(1, config.max_radius_px + 1, dtype=jnp.int32)
    opened = lax.scan(step, zimin, radii)[1]
    return Prepared(jnp.concatenate([zimin[None], opened]), domain, filled & ~low, xyz, valid, hw)


def _object_cells(prep: Prepared, slope: Float[Array, ""], radius_px: Int[Array, ""], cell_m: float,
                  temperature) -> Mask | Raster:
    """Object test of the progressive filter over radii 1..radius_px (hard bool or weight).

    All prepared radii are tested; those beyond the traced `radius_px` never count, so one
    compiled program serves every window of the grid."""
    s = prep.surfaces
    dtype = s.dtype
    n_radii = s.shape[0] - 1
    radii = jnp.arange(1, n_radii + 1, dtype=jnp.int32)
    thresholds = slope * radii.astype(dtype) * jnp.asarray(cell_m, dtype)   # as progressive_filter
    active = radii <= radius_px
    if temperature is None:
        objects = jnp.zeros(s.shape[1:], jnp.bool_)
        for r in range(1, n_radii + 1):
            test = stages.is_object(s[r - 1], s[r], thresholds[r - 1])
            objects = objects | (active[r - 1] & prep.domain & test)
        return objects
    drops = s[:-1] - s[1:]
    margins = jnp.where(active[:, None, None], drops - thresholds[:, None, None], -jnp.inf)
    weight = relax.soft_or_max(margins, temperature)
    return jnp.where(prep.domain, weight, jnp.zeros((), dtype))


def _neighbour_mean(u: Raster) -> Raster:
    """Mean of the in-raster 4-neighbours of each cell (zero flux at the border)."""
    h, w = u.shape
    p = jnp.pad(u, 1)
    total = p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]
    rows = jnp.arange(h, dtype=jnp.int32)
    cols = jnp.arange(w, dtype=jnp.int32)
    count = (((rows > 0).astype(u.dtype) + (rows < h - 1).astype(u.dtype))[:, None]
             + ((cols > 0).astype(u.dtype) + (cols < w - 1).astype(u.dtype))[None, :])
    return total / jnp.maximum(count, jnp.ones((), u.dtype))


def soft_inpaint(z: Raster, keep: Raster, *, config: Config, domain: Mask | None = None,
                 sweeps: int = SOFT_SWEEPS) -> Raster:
    """Soft-masked harmonic fill: `u = keep * z + (1 - keep) * mean_4(u)` (`keep` in [0, 1]).

    Args:
      z: finite surface `(h, w)` [m] (ZImin).
      keep: weight of each cell's own value, `(h, w)`; 0/1 gives the plain harmonic fill.
      config: the inpainting settings (`stages.inpaint` for the start).
      domain: the tile's own cells `(h, w)` (None: all); cells outside keep the start value.
      sweeps: Jacobi sweeps (static); the gradient reaches `sweeps` cells from a cell.

    Returns:
      `(h, w)` [m], differentiable in `keep` and `z`.
    """
    half = jnp.asarray(0.5, keep.dtype)
    start = lax.stop_gradient(stages.inpaint(z, keep > half, config=config, domain=domain))

    def sweep(u, _):
        new = keep * z + (1 - keep) * _neighbour_mean(u)
        return (new if domain is None else jnp.where(domain, new, start)), None

    u, _ = lax.scan(sweep, start, None, length=sweeps)
    return u


def ground_weight(prep: Prepared, params: Params, *, config: Config,
                  radius_px: int | Int[Array, ""] | None = None,
                  temperature: float | Float[Array, ""] | None = None,
                  sweeps: int = SOFT_SWEEPS) -> PointMask | Float[Array, " n"]:
    """SMRF steps 3-5 on a prepared tile: ground labels (hard) or ground weights (relaxed).

    Args:
      prep: from `prepare_tile` with a window >= `config.window_m` (same shape and cell).
      params: thresholds (traced).
      config: static settings (cell, inpainting).
      radius_px: the largest opening tested, `ceil(window / cell)` (may be traced; default
        `config.max_radius_px`); at most the prepared number of openings.
      temperature: None for the plain filter's hard tests, else the softness [m].

    Returns:
      bool `(n,)` (hard; equals `gfjax.smrf.programs.classify_tile`) or float `(n,)` in [0, 1] (relaxed);
      False / 0 where `~prep.valid`.
    """
    if radius_px is None:
        radius_px = config.max_radius_px
    if isinstance(radius_px, int) and radius_px + 1 > prep.surfaces.shape[0]:
        raise ValueError(f"prepared for {prep.surfaces.shape[0] - 1} openings, asked for {radius_px}")
    radius_px = jnp.asarray(radius_px, jnp.int32)
    xy, z = prep.xyz[:, :2], prep.xyz[:, 2]
    zimin = prep.surfaces[0]
    objects = _object_cells(prep, params.slope, radius_px, config.cell_m, temperature)
    if temperature is None:
        zipro = stages.inpaint(zimin, prep.candidate & ~objects, config=config, domain=prep.domain)
        slope = stages.gradient_magnitude(zipro, prep.domain, cell_m=config.cell_m)
    else:
        keep = jnp.where(prep.candidate, 1 - objects, jnp.zeros((), zimin.dtype))
        zipro = soft_inpaint(zimin, keep, config=config, domain=prep.domain, sweeps=sweeps)
        slope = stages.gradient_magnitude(lax.stop_gradient(zipro), prep.domain, cell_m=config.cell_m)
    surface_at = sample_bilinear(replicate_edges(zipro, prep.hw), xy, cell_m=config.cell_m)
    slope_at = sample_bilinear(replicate_edges(slope, prep.hw), xy, cell_m=config.cell_m)
    dz = z - surface_at
    if temperature is None:
        return prep.valid & stages.is_ground_point(dz, slope_at, params)
    limit = params.threshold_m + params.scalar * slope_at
    weight = relax.less_equal(jnp.abs(dz), limit, temperature)
    return jnp.where(prep.valid, weight, jnp.zeros((), weight.dtype))


def radius_for(config: Config, window_m: float) -> int:
    """Openings of a window: `Config.max_radius_px` of `config` with `window_m`."""
    return dataclasses.replace(config, window_m=float(window_m)).max_radius_px



def _ground_weight(prep, values, *, config, static_px, temperature):
    return ground_weight(prep, make_params(values), config=config, radius_px=static_px, temperature=temperature)


TUNER = GradientTuner(
    name="smrf", bounds=BOUNDS, units=UNITS, config_type=Config, static="window_m",
    grid=GRID["window_m"], prepare_tile=prepare_tile.__wrapped__, ground_weight=_ground_weight,
    static_px=radius_for, default_static=lambda config: Config().window_m, grid_keys=("window_m",),
    prepared_config=lambda config, grid: dataclasses.replace(
        config, window_m=float(max(max(grid), config.window_m))))
