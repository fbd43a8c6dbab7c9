"""PMF's stages as compiled programs: one tile, or a batch of tiles under `jax.vmap`.

As SMRF's (`gfjax.smrf.programs`): three jitted programs per static setting, the costly
raster one compiled once per raster shape and only the cheap point ones again for another
point capacity, each through `gfjax.aot` (kept across processes when it is on).
"""
from __future__ import annotations

import functools

import jax
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from gfjax import aot
from gfjax._types import PointMask
from gfjax.io.tiled import without_tiling
from gfjax.pmf.config import Config, Params
from gfjax.pmf.stages import Diagnostics, classify_points, rasterize_min, surfaces

__all__ = ["classify_tile", "classify_batch"]

Host = Array | np.ndarray        # a batch arrives from the tiler as host numpy


@functools.cache
def _compiled(config: Config, shape: tuple[int, int], batched: bool):
    raster = functools.partial(rasterize_min, cell_m=config.cell_m, shape=shape)
    middle = functools.partial(surfaces, config=config)
    points = functools.partial(classify_points, config=config)
    if batched:
        raster, middle = jax.vmap(raster), jax.vmap(middle)
        points = jax.vmap(points, in_axes=(0, 0, 0, None))
    return jax.jit(raster), jax.jit(middle), jax.jit(points)


def classify_tile(xyz: Float[Host, "n 3"], valid: Bool[Host, " n"], hw: Int[Host, " 2"], params: Params, *,
                  config: Config, shape: tuple[int, int]) -> tuple[PointMask, Diagnostics]:
    """PMF on one tile (Zhang et al. 2003).

    Args:
      xyz: tile-local coordinates, float32 `(n, 3)` [m], x/y relative to the raster's south-west
        corner; rows with `~valid` are ignored.
      valid: points to classify, bool `(n,)`.
      hw: int32 `(2,)` rows and columns of the tile's own extent inside `shape`.
      params: traced thresholds; config: static settings; shape: static raster `(h, w)`.

    Returns:
      `(ground, diagnostics)`: bool `(n,)` (False where `~valid`) and `Diagnostics`.
    """
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=False)


def classify_batch(xyz: Float[Host, "b n 3"], valid: Bool[Host, "b n"], hw: Int[Host, "b 2"],
                   params: Params, *, config: Config, shape: tuple[int, int]) -> tuple[Bool[Array, "b n"], Diagnostics]:
    """`classify_tile` under `jax.vmap` over a batch of padded tiles (params shared)."""
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=True)


def _run(xyz, valid, hw, params, config: Config, shape: tuple[int, int], *, batched: bool):
    config = without_tiling(config)
    raster, middle, points = _compiled(config, shape, batched)
    tag = (config, shape, batched)
    z_min, filled = aot.call(raster, xyz, valid, tag=("gfjax.pmf.rasterize_min", *tag))
    opened, diag = aot.call(middle, z_min, filled, hw, tag=("gfjax.pmf.surfaces", *tag))
    ground = aot.call(points, xyz, valid, opened, params, tag=("gfjax.pmf.classify_points", *tag))
    return ground, diag
