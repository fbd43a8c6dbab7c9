"""PMF with relaxed thresholds, composed from `gfjax.pmf.stages` (Zhang et al. 2003).

PMF's tuned parameters (SPEC section 7: slope, initial and max distance) act only at the
point test: a point stays ground while, at every window k, its height above the k-th opened
surface is below `dh_k = min(slope (w_k - w_{k-1}) c + dh0, dh_max)` (Eq. 7; PDAL's
`z - opened < dh_k`). The openings do not depend on them, so `prepare_tile` computes them once
(`stages.minimum_surface`, `stages.progressive_openings`). The relaxed ground weight is

    sigmoid(min_k(dh_k - dz_k) / T)  =  1 - relax.soft_or_max(dz_k - dh_k, T),

with `dh_k` from `stages.thresholds_m` (differentiable; `max_distance_m` receives a gradient
only through the windows whose threshold is capped, `initial_distance_m` and `slope` through
the others). With `temperature=None` the labels are `stages.classify_points` itself, so they
equal the plain filter bit for bit (tested).

`gfjax.pmf.tuning.TUNER` plugs it into `gfjax.tune.fit`, the guard and `gfjax tune --method pmf`
(the window series is not searched).
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from gfjax._types import Mask, PointMask, Points
from gfjax.pmf import stages
from gfjax.pmf.config import Config, Params
from gfjax.raster.grid import cell_index, domain_mask
from gfjax.tune import relax
from gfjax.tune.params import bound
from gfjax.tune.tuners import GradientTuner

__all__ = ["TUNER", "BOUNDS", "UNITS", "Prepared", "prepare_tile", "ground_weight", "make_params"]

BOUNDS = (
    bound(Params, "slope", 0.1, 3.0, "1 (rise over run)"),
    bound(Params, "initial_distance_m", 0.05, 1.0, "m"),
    bound(Params, "max_distance_m", 0.5, 6.0, "m"),
)
UNITS = {b.name: b.unit for b in BOUNDS}


class Prepared(NamedTuple):
    """One tile's parameter-free PMF data.

    Attributes:
      opened: float32 `(k, h, w)` the progressively opened surfaces [m].
      domain: bool `(h, w)` the tile's cells.
      xyz: float32 `(n, 3)`; valid: bool `(n,)`.
    """

    opened: Float[Array, "k h w"]
    domain: Mask
    xyz: Points
    valid: PointMask


def make_params(values: Float[Array, " 3"]) -> Params:
    """PMF `Params` from a vector ordered as `BOUNDS`."""
    return Params(slope=values[0], initial_distance_m=values[1], max_distance_m=values[2])


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def prepare_tile(xyz: Points, valid: PointMask, hw: Int[Array, 2], *, config: Config,
                 shape: tuple[int, int]) -> Prepared:
    """The minimum surface and its openings, exactly as `gfjax.pmf.programs.classify_tile` computes them."""
    domain = domain_mask(hw, shape)
    zimin, _ = stages.minimum_surface(xyz, valid, domain, cell_m=config.cell_m, shape=shape)
    opened = stages.progressive_openings(zimin, domain, windows_px=config.windows_px)
    return Prepared(opened, domain, xyz, valid)


def ground_weight(prep: Prepared, params: Params, *, config: Config,
                  temperature: float | Float[Array, ""] | None = None) -> PointMask | Float[Array, " n"]:
    """PMF's point test on a prepared tile: hard labels (`temperature=None`, equal to
    `stages.classify_points`) or relaxed ground weights in [0, 1], float `(n,)`; 0 where
    `~valid` or outside the raster."""
    if temperature is None:
        return stages.classify_points(prep.xyz, prep.valid, prep.opened, params, config=config)
    _, h, w = prep.opened.shape
    row, col, inside = cell_index(prep.xyz[:, :2], cell_m=config.cell_m, shape=(h, w))
    dh = stages.thresholds_m(params, windows_px=config.windows_px, cell_m=config.cell_m)
    dz = prep.xyz[None, :, 2] - prep.opened[:, row, col]                  # (k, n)
    weight = 1 - relax.soft_or_max(dz - dh[:, None], temperature)
    return jnp.where(prep.valid & inside, weight, jnp.zeros((), weight.dtype))


def _ground_weight(prep, values, *, config, static_px, temperature):
    del static_px                       # the window series is static (config.windows_px)
    return ground_weight(prep, make_params(values), config=config, temperature=temperature)


TUNER = GradientTuner(
    name="pmf", bounds=BOUNDS, units=UNITS, config_type=Config, static=None, grid=(),
    prepare_tile=prepare_tile.__wrapped__, ground_weight=_ground_weight,
    static_px=lambda config, value: 0, default_static=lambda config: config.max_window_m,
    prepared_config=lambda config, grid: config)
