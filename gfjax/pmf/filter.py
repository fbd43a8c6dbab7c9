"""`gfjax.pmf.filter`: the progressive morphological filter (Zhang et al. 2003) on a whole cloud.

1. ZImin: the lowest point per cell, empty cells filled from the nearest non-empty cell;
2. for windows `w_k = 2 b^k + 1` cells (3, 5, 9, 17, 33 by default): open the surface with a
   square window of `w_k` cells; a point whose height above the opened surface is not below
   `dh_k = min(slope (w_k - w_{k-1}) c + dh0, dh_max)` is non-ground; the opened surface
   becomes the surface;
3. the points that passed every window are ground.

The cloud is cut into buffered tiles (`gfjax.io.tiles`); each batch of equal-shape tiles runs
through one jitted, vmapped call of `stages.classify_batch`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError
from gfjax.io import tiles as tiling
from gfjax.io.cloud import Cloud
from gfjax.pmf import stages
from gfjax.pmf.config import Config, Params
from gfjax.result import Result

__all__ = ["filter", "PMFDiagnostics", "MAX_BATCH"]

MAX_BATCH = 8


class PMFDiagnostics(NamedTuple):
    """The PMF rasters of the whole cloud (tile cores mosaicked), host numpy, row 0 = north.

    Attributes:
      zimin: lowest z per cell, gaps filled `(h, w)` [m, the cloud's vertical frame].
      surface: the last opened surface `(h, w)` [m].
      empty: cells without a point, bool `(h, w)`.
      origin_m: float64 `(2,)`, x and y of the raster's south-west corner [m].
      cell_m: cell side [m]; windows_px: the window sizes used [cells]; n_tiles: tiles filtered.
    """

    zimin: np.ndarray
    surface: np.ndarray
    empty: np.ndarray
    origin_m: np.ndarray
    cell_m: float
    windows_px: tuple[int, ...]
    n_tiles: int


def _mosaic(tiles, diags, config: Config) -> PMFDiagnostics:
    """Tile cores pasted into one raster over the cloud's extent (row 0 = north)."""
    width = max(t.core_px[2] for t in tiles)
    height = max(t.core_px[3] for t in tiles)
    out = {"zimin": np.zeros((height, width)), "surface": np.zeros((height, width)),
           "empty": np.zeros((height, width), bool)}
    for tile, diag in zip(tiles, diags):
        c0, r0, c1, r1 = tile.core_px
        wc, wr = tile.window_px
        h = tile.shape[0]
        src_rows = slice(h - (r1 - wr), h - (r0 - wr))
        dst_rows = slice(height - r1, height - r0)
        for name in out:
            out[name][dst_rows, c0:c1] = getattr(diag, name)[src_rows, c0 - wc:c1 - wc]
    z0 = float(tiles[0].origin_m[2])
    out["zimin"] += z0
    out["surface"] += z0
    origin = tiles[0].origin_m[:2] - np.asarray(tiles[0].window_px, np.float64) * config.cell_m
    return PMFDiagnostics(**out, origin_m=origin, cell_m=config.cell_m, windows_px=config.windows_px,
                          n_tiles=len(tiles))


def filter(cloud: Cloud, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False) -> Result:  # noqa: A001 (the package API name)
    """Classify a cloud's ground points with PMF (Zhang et al. 2003).

    Args:
      cloud: the point cloud (any units; filtered in metres).
      config: static settings (default: cell 1 m, max window 33 m, exponential windows, b = 2).
      params: thresholds (default: slope 1, initial distance 0.15 m, max distance 2.5 m).
      returns: "all" or "last": which returns are filtered.
      progress: show a progress bar over tile batches.

    Returns:
      `Result(ground, diagnostics)`: `ground` bool `(n,)`, False for ignored points;
      `diagnostics` a `PMFDiagnostics` (None for a cloud with no usable point).
    """
    config = Config() if config is None else config
    params = Params() if params is None else params
    if not isinstance(config, Config):
        raise InputError(f"config must be a gfjax.pmf.Config, got {type(config).__name__}")
    if not isinstance(params, Params):
        raise InputError(f"params must be a gfjax.pmf.Params, got {type(params).__name__}")
    try:
        params.check()
        use = cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: {err}") from None
    tiles = tiling.split(cloud.xyz_m, tile_size_m=config.tile_size_m, buffer_m=config.buffer_m,
                         cell_m=config.cell_m, use=use)
    if not tiles:
        return Result(ground=np.zeros(cloud.n_points, bool), diagnostics=None)
    position = {id(tile): i for i, tile in enumerate(tiles)}
    labels: list[np.ndarray | None] = [None] * len(tiles)
    diags: list[stages.Diagnostics | None] = [None] * len(tiles)
    groups = list(tiling.batches(tiles, max_batch=MAX_BATCH))
    if progress:
        from tqdm.auto import tqdm
        groups = tqdm(groups, desc="pmf tiles", unit="batch")
    for batch in groups:
        ground, diag = stages.classify_batch(batch.xyz, batch.valid, batch.hw, params, config=config,
                                             shape=batch.shape)
        ground = np.asarray(ground)
        diag = stages.Diagnostics(*(np.asarray(a) for a in diag))
        for b, tile in enumerate(batch.tiles):
            i = position[id(tile)]
            labels[i] = ground[b, :tile.n_points]
            h, w = tile.shape
            rows = slice(batch.shape[0] - h, batch.shape[0])
            diags[i] = stages.Diagnostics(*(a[b, rows, :w] for a in diag))
    ground = tiling.merge(cloud.n_points, tiles, labels) & use
    return Result(ground=ground, diagnostics=_mosaic(tiles, diags, config))
