"""SMRF's stages as compiled programs: one tile, or a batch of tiles under `jax.vmap`.

The stages (`gfjax.smrf.stages`) are pure array functions. Here they become three jitted
programs per static setting: the costly raster one compiles once per raster shape, and only
the cheap point ones again for another point capacity. Each goes through `gfjax.aot`, which
keeps compiled programs across processes when it is on (the command line and `import gfjax`
turn it on) and is the plain jitted call otherwise, and under tracing.
"""
from __future__ import annotations

import functools

import jax
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from gfjax import aot
from gfjax._types import PointMask
from gfjax.io.tiled import without_tiling
from gfjax.smrf.config import Config, Params
from gfjax.smrf.stages import Diagnostics, classify_points, rasterize_min, surfaces

__all__ = ["classify_tile", "classify_batch"]

Host = Array | np.ndarray        # a batch arrives from the tiler as host numpy


@functools.cache
def _compiled(config: Config, shape: tuple[int, int], batched: bool):
    """The three jitted stages of a tile (or of a batch, under `vmap`) for one static setting."""
    raster = functools.partial(rasterize_min, cell_m=config.cell_m, shape=shape)
    middle = functools.partial(surfaces, config=config)
    points = functools.partial(classify_points, cell_m=config.cell_m)
    if batched:
        raster = jax.vmap(raster)
        middle = jax.vmap(middle, in_axes=(0, 0, 0, None))
        points = jax.vmap(points, in_axes=(0, 0, 0, 0, 0, None))
    return jax.jit(raster), jax.jit(middle), jax.jit(points)


def classify_tile(xyz: Float[Host, "n 3"], valid: Bool[Host, " n"], hw: Int[Host, "2"], params: Params, *,
                  config: Config, shape: tuple[int, int]) -> tuple[PointMask, Diagnostics]:
    """SMRF on one tile (Pingel et al. 2013, Sec. 2.1-2.4).

    Args:
      xyz: tile-local coordinates, float32 `(n, 3)` [m], x/y relative to the raster's
        south-west corner. Padding rows are ignored through `valid`.
      valid: points to classify, bool `(n,)`.
      hw: int32 `(2,)` rows and columns of the tile's own extent inside `shape`.
      params: traced thresholds.
      config: static settings; shape: static raster `(h, w)` (a padding bucket).

    Returns:
      `(ground, diagnostics)`: bool `(n,)` (False where `~valid`) and the tile's `Diagnostics`.
    """
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=False)


def classify_batch(xyz: Float[Host, "b n 3"], valid: Bool[Host, "b n"], hw: Int[Host, "b 2"],
                   params: Params, *, config: Config, shape: tuple[int, int]) -> tuple[Bool[Array, "b n"], Diagnostics]:
    """`classify_tile` under `jax.vmap` over a batch of padded tiles (params shared); the
    diagnostics gain a leading batch axis."""
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=True)


def _run(xyz, valid, hw, params, config: Config, shape: tuple[int, int], *, batched: bool):
    config = without_tiling(config)
    raster, middle, points = _compiled(config, shape, batched)
    tag = (config, shape, batched)
    z_min, filled = aot.call(raster, xyz, valid, tag=("gfjax.smrf.rasterize_min", *tag))
    diag = aot.call(middle, z_min, filled, hw, params, tag=("gfjax.smrf.surfaces", *tag))
    ground = aot.call(points, xyz, valid, diag.zipro, diag.slope, hw, params, tag=("gfjax.smrf.classify_points", *tag))
    return ground, diag
