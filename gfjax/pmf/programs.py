"""PMF's stages as compiled programs: one tile, or a batch of tiles under `jax.vmap`.

As SMRF's (`gfjax.smrf.programs`): three programs per static setting and raster shape
(`gfjax.aot.programs`), the costly raster one compiled once per raster shape and only the
cheap point ones again for another point capacity.
"""
from __future__ import annotations

import functools

from jaxtyping import Bool, Float, Int

from gfjax import aot
from gfjax._types import Host
from gfjax.pmf.config import Config, Params
from gfjax.pmf.stages import TileDiagnostics, classify_points, rasterize_min, surfaces
from gfjax.tiling import chunks
from gfjax.tiling.tiles import WindowRows

__all__ = ["classify_tile", "classify_batch"]


@functools.cache
def _programs(config: Config, shape: tuple[int, int], batched: bool):
    """The three programs of a tile (or of a batch) for one static setting and raster shape."""
    return aot.programs("gfjax.pmf", [
        ("rasterize_min", functools.partial(rasterize_min, cell_m=config.cell_m, shape=shape), 0),
        ("surfaces", functools.partial(surfaces, config=config), 0),
        ("classify_points", functools.partial(classify_points, config=config), (0, 0, 0, None)),
    ], key=(config, shape), batched=batched)


def classify_tile(xyz: Float[Host, "n 3"], valid: Bool[Host, " n"], hw: Int[Host, " 2"], params: Params, *,
                  config: Config, shape: tuple[int, int]) -> tuple[Bool[Host, " n"], TileDiagnostics]:
    """PMF on one tile (Zhang et al. 2003).

    Args:
      xyz: tile-local coordinates, float32 `(n, 3)` [m], x/y relative to the raster's south-west
        corner; rows with `~valid` are ignored.
      valid: points to classify, bool `(n,)`.
      hw: int32 `(2,)` rows and columns of the tile's own extent inside `shape`.
      params: traced thresholds; config: static settings; shape: static raster `(h, w)`.

    Returns:
      `(ground, diagnostics)`: bool `(n,)` (False where `~valid`) and `TileDiagnostics`.
    """
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=False)


def classify_batch(xyz: Float[Host, "b m 3"] | WindowRows, valid: Bool[Host, "b n"], hw: Int[Host, "b 2"],
                   params: Params, *, config: Config, shape: tuple[int, int]) -> tuple[Bool[Host, "b n"], TileDiagnostics]:
    """`classify_tile` under `jax.vmap` over a batch of padded tiles (params shared). `xyz`
    may hold fewer rows `m` than the capacity `n` when they run a chunk at a time
    (`batches.TileBatch`; a lone window's `WindowRows`, a batch of one): the rest is padding."""
    return _run(xyz, valid, hw, params, config, tuple(shape), batched=True)


def _run(xyz, valid, hw, params, config: Config, shape: tuple[int, int], *, batched: bool):
    raster, middle, points = _programs(config, shape, batched)
    z_min, filled = chunks.lowest(raster, xyz, valid)          # a large window a chunk at a time
    opened, diag = middle(z_min, filled, hw)
    return chunks.labels(points, xyz, valid, opened, params), diag
