"""SMRF's stages as compiled programs: one tile, or a batch of tiles under `jax.vmap`.

The stages (`gfjax.smrf.stages`) are pure array functions. Here they become three programs
per static setting (`gfjax.aot.programs`): the costly raster one compiles once per raster
shape, the cheap point ones again for another point capacity; each is kept across processes
when the program cache is on (the command line and `import gfjax` turn it on).
"""
from __future__ import annotations

import functools

from jaxtyping import Bool, Float, Int

from gfjax import aot
from gfjax._types import Host
from gfjax.smrf.config import Config, Params
from gfjax.smrf.stages import TileDiagnostics, classify_points, rasterize_min, surfaces
from gfjax.tiling import chunks
from gfjax.tiling.tiles import WindowRows

__all__ = ["classify_tile", "classify_batch"]


@functools.cache
def _programs(config: Config, shape: tuple[int, int], batched: bool):
    """The three programs of a tile (or of a batch) for one static setting and raster shape."""
    return aot.programs("gfjax.smrf", [
        ("rasterize_min", functools.partial(rasterize_min, cell_m=config.cell_m, shape=shape), 0),
        ("surfaces", functools.partial(surfaces, config=config), (0, 0, 0, None)),
        ("classify_points", functools.partial(classify_points, cell_m=config.cell_m), (0, 0, 0, 0, 0, None)),
    ], key=(config, shape), batched=batched)


def classify_tile(xyz: Float[Host, "n 3"], valid: Bool[Host, " n"], hw: Int[Host, 2], params: Params, *,
                  config: Config, shape: tuple[int, int]) -> tuple[Bool[Host, " n"], TileDiagnostics]:
    """SMRF on one tile (Pingel et al. 2013, Sec. 2.1-2.4).

    Args:
      xyz: tile-local coordinates, float32 `(n, 3)` [m], x/y relative to the raster's
        south-west corner. Padding rows are ignored through `valid`.
      valid: points to classify, bool `(n,)`.
      hw: int32 `(2,)` rows and columns of the tile's own extent inside `shape`.
      params: traced thresholds.
      config: static settings; shape: static raster `(h, w)` (a padding bucket).

    Returns:
      `(ground, diagnostics)`: bool `(n,)` (False where `~valid`) and the tile's `TileDiagnostics`.
    """
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=False)


def classify_batch(xyz: Float[Host, "b m 3"] | WindowRows, valid: Bool[Host, "b n"], hw: Int[Host, "b 2"],
                   params: Params, *, config: Config, shape: tuple[int, int]) -> tuple[Bool[Host, "b n"], TileDiagnostics]:
    """`classify_tile` under `jax.vmap` over a batch of padded tiles (params shared); the
    diagnostics gain a leading batch axis. `xyz` may hold fewer rows `m` than the capacity `n`
    when they run a chunk at a time (`batches.TileBatch`; a lone window's `WindowRows`, a
    batch of one): the rest is padding."""
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=True)


def _run(xyz, valid, hw, params, config: Config, shape: tuple[int, int], *, batched: bool):
    raster, middle, points = _programs(config, shape, batched)
    z_min, filled = chunks.lowest(raster, xyz, valid)          # a large window a chunk at a time
    diag = middle(z_min, filled, hw, params)
    return chunks.labels(points, xyz, valid, diag.zipro, diag.slope, hw, params), diag
