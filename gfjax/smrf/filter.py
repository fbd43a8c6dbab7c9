"""`gfjax.smrf.filter`: SMRF on a whole cloud, tile batches under `jax.vmap`.

Pingel, Clarke & McBride (2013), "An improved simple morphological filter for the terrain
classification of airborne LIDAR data", ISPRS J. 77:21-30. Reads like PDAL's `filters.smrf`:

1. ZImin, the lowest point per cell, empty cells inpainted;
2. low outliers: the progressive filter on -ZImin (slope 5, one-cell window);
3. the progressive opening of ZImin with disks r = 1..ceil(window / cell), object cells where
   the surface drops by more than slope * r * cell;
4. ZIpro: ZImin without empty, low-outlier and object cells, inpainted;
5. ground points: |z - ZIpro(x, y)| <= threshold + scalar * slope(ZIpro) (bilinear).

The cloud is cut into buffered tiles (`gfjax.io.tiles`); each batch of equal-shape tiles runs
through the jitted, vmapped stages of `stages.classify_batch`.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError
from gfjax.io import tiles as tiling
from gfjax.io.cloud import Cloud
from gfjax.result import Result
from gfjax.smrf import stages
from gfjax.smrf.config import Config, Params

__all__ = ["filter", "SMRFDiagnostics", "run_tiles"]

MAX_BATCH = 8


class SMRFDiagnostics(NamedTuple):
    """The SMRF rasters of the whole cloud (tile cores mosaicked), host numpy, row 0 = north.

    Attributes:
      zimin, zipro: surfaces `(h, w)` [m, absolute heights in the cloud's vertical frame].
      slope: ZIpro gradient magnitude `(h, w)`, rise over run.
      empty, low_outliers, object_cells: bool `(h, w)`.
      origin_m: float64 `(2,)`, x and y of the raster's south-west corner [m].
      cell_m: cell side [m].
      n_tiles: how many tiles were filtered.
    """

    zimin: np.ndarray
    zipro: np.ndarray
    slope: np.ndarray
    empty: np.ndarray
    low_outliers: np.ndarray
    object_cells: np.ndarray
    origin_m: np.ndarray
    cell_m: float
    n_tiles: int


def run_tiles(tiles: list[tiling.Tile], params: Params, config: Config, *, progress: bool = False,
              max_batch: int = MAX_BATCH, keep_diagnostics: bool = True):
    """Classify tiles batch by batch (`stages.classify_batch`, one compile per batch shape).

    Returns:
      `(labels, diagnostics)`: per tile a bool `(tile.n_points,)` ground array, and per tile a
      `stages.Diagnostics` cropped to the tile's own extent (or None when not kept).
    """
    position = {id(tile): i for i, tile in enumerate(tiles)}
    labels: list[np.ndarray | None] = [None] * len(tiles)
    diagnostics: list[stages.Diagnostics | None] = [None] * len(tiles)
    groups = list(tiling.batches(tiles, max_batch=max_batch))
    if progress:
        from tqdm.auto import tqdm
        groups = tqdm(groups, desc="smrf tiles", unit="batch")
    for batch in groups:
        ground, diag = stages.classify_batch(batch.xyz, batch.valid, batch.hw, params,
                                             config=config, shape=batch.shape)
        ground = np.asarray(ground)
        diag = stages.Diagnostics(*(np.asarray(a) for a in diag)) if keep_diagnostics else None
        for b, tile in enumerate(batch.tiles):
            i = position[id(tile)]
            labels[i] = ground[b, :tile.n_points]
            if diag is not None:
                h, w = tile.shape
                rows = slice(batch.shape[0] - h, batch.shape[0])
                diagnostics[i] = stages.Diagnostics(*(a[b, rows, :w] for a in diag))
    return labels, diagnostics


def _mosaic(tiles: list[tiling.Tile], diags: list[stages.Diagnostics], config: Config) -> SMRFDiagnostics:
    """Tile cores pasted into one raster over the cloud's extent (row 0 = north)."""
    width = max(t.core_px[2] for t in tiles)
    height = max(t.core_px[3] for t in tiles)
    z0 = float(tiles[0].origin_m[2])
    out = {name: np.zeros((height, width), dtype=np.float64 if name in ("zimin", "zipro", "slope") else bool)
           for name in ("zimin", "zipro", "slope", "empty", "low_outliers", "object_cells")}
    for tile, diag in zip(tiles, diags):
        c0, r0, c1, r1 = tile.core_px
        wc, wr = tile.window_px
        h = tile.shape[0]
        src_rows = slice(h - (r1 - wr), h - (r0 - wr))             # rows from the south -> north-up
        dst_rows = slice(height - r1, height - r0)
        for name in out:
            out[name][dst_rows, c0:c1] = getattr(diag, name)[src_rows, c0 - wc:c1 - wc]
    out["zimin"] += z0
    out["zipro"] += z0
    origin = tiles[0].origin_m[:2] - np.asarray(tiles[0].window_px, np.float64) * config.cell_m
    return SMRFDiagnostics(**out, origin_m=origin, cell_m=config.cell_m, n_tiles=len(tiles))


def filter(cloud: Cloud, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False) -> Result:  # noqa: A001 (the package API name)
    """Classify a cloud's ground points with SMRF (Pingel et al. 2013).

    Args:
      cloud: the point cloud (any units; filtered in metres).
      config: static settings (default `Config()`: cell 1 m, window 18 m, tiles 500 m / 50 m).
      params: thresholds (default `Params()`: slope 0.15, threshold 0.5 m, scalar 1.25).
      returns: "all" or "last": which returns are filtered.
      progress: show a progress bar over tile batches.

    Returns:
      `Result(ground, diagnostics)`: `ground` bool `(n,)`, False for ignored points (noise,
      withheld, and non-last returns with `returns="last"`); `diagnostics` an
      `SMRFDiagnostics` (None for a cloud with no usable point).
    """
    config = Config() if config is None else config
    params = Params() if params is None else params
    if not isinstance(config, Config):
        raise InputError(f"config must be a gfjax.smrf.Config, got {type(config).__name__}")
    if not isinstance(params, Params):
        raise InputError(f"params must be a gfjax.smrf.Params, got {type(params).__name__}")
    try:
        params.check()
        use = cloud.filter_mask(returns)
    except ValueError as err:
        raise InputError(f"{cloud.name}: {err}") from None
    tiles = tiling.split(cloud.xyz_m, tile_size_m=config.tile_size_m, buffer_m=config.buffer_m,
                         cell_m=config.cell_m, use=use)
    if not tiles:
        return Result(ground=np.zeros(cloud.n_points, bool), diagnostics=None)
    labels, diags = run_tiles(tiles, params, config, progress=progress)
    ground = tiling.merge(cloud.n_points, tiles, labels)
    return Result(ground=ground, diagnostics=_mosaic(tiles, diags, config))
