"""`gfjax.smrf.filter`: SMRF on a whole cloud, tile batches under `jax.vmap`.

Pingel, Clarke & McBride (2013), "An improved simple morphological filter for the terrain
classification of airborne LIDAR data", ISPRS J. 77:21-30. Reads like PDAL's `filters.smrf`:

1. ZImin, the lowest point per cell, empty cells inpainted;
2. low outliers: the progressive filter on -ZImin (slope 5, one-cell window);
3. the progressive opening of ZImin with disks r = 1..ceil(window / cell), object cells where
   the surface drops by more than slope * r * cell;
4. ZIpro: ZImin without empty, low-outlier and object cells, inpainted;
5. ground points: |z - ZIpro(x, y)| <= threshold + scalar * slope(ZIpro) (bilinear).

The cloud is cut into buffered tiles (`gfjax.tiling.tiles`); each batch of equal-shape tiles runs
through the jitted, vmapped stages of `programs.classify_batch` (`gfjax.tiling.driver` drives the
tiles and mosaics the tile cores).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax import adaptive, cache
from gfjax.io.cloud import CloudView
from gfjax.result import Result
from gfjax.smrf import programs
from gfjax.smrf.config import HIDES_LOW_OUTLIERS, MAX_BATCH, Config, Params, adapt
from gfjax.tiling import driver
from gfjax.tiling.tiles import Tiling

__all__ = ["filter", "warm", "Diagnostics"]

_RASTERS = ("zimin", "zipro", "slope", "empty", "low_outliers", "object_cells")


class Diagnostics(NamedTuple):
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


@cache.persistent
@adaptive.follows(adapt, Config, Params, hides_low_outliers=HIDES_LOW_OUTLIERS)
def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False, tiling: Tiling | None = None) -> Result:  # noqa: A001 (the package API name)
    """Classify a cloud's ground points with SMRF (Pingel et al. 2013).

    Args:
      cloud: the point cloud (any units; filtered in metres).
      config: static settings; default `Config()` (cell 1 m, window 18 m) with the values
        that follow the cloud (`adapt`: a coarser cell for sparse clouds), and ground spikes
        dropped (`gfjax.spikes`). A given Config is used as it is, with no spike guard.
      params: thresholds (default `Params()`: slope 0.15, threshold 0.5 m, scalar 1.25).
      returns: "all" or "last": which returns are filtered.
      progress: show a progress bar over tile batches.
      tiling: how the cloud is cut into buffered tiles (default `Tiling()`: 500 m cores,
        50 m buffers; `gfjax.tiling.tiles.Tiling`).

    Returns:
      `Result(ground, diagnostics)`: `ground` bool `(n,)`, False for ignored points (noise,
      withheld, and non-last returns with `returns="last"`); `diagnostics` an
      `Diagnostics` (None for a cloud with no usable point, and for one whose groups of
      points far apart were filtered one by one: `gfjax.tiling.driver.classify_groups`).
    """
    done = driver.filter_cloud(cloud, config, params, returns, tiling=tiling, config_type=Config, params_type=Params,
                              package="gfjax.smrf", classify_batch=programs.classify_batch, max_batch=MAX_BATCH,
                              rasters=_RASTERS, heights=("zimin", "zipro"), progress=progress)
    if done.cores is None:
        return Result(ground=done.ground, diagnostics=None)
    return Result(ground=done.ground, diagnostics=Diagnostics(
        **done.cores.rasters, origin_m=done.cores.origin_m, cell_m=done.config.cell_m, n_tiles=done.n_tiles))


@cache.persistent
def warm(config: Config | None = None, params: Params | None = None, *, progress: bool = False,
         tiling: Tiling | None = None) -> int:
    """Prepare the programs `filter` runs on a file of one tile of any size (`driver.warm`):
    later first runs load them instead of compiling. Returns the number of shapes prepared."""
    config, params = config or Config(), params or Params()
    return driver.warm(programs.classify_batch, params, config, tiling=tiling, progress=progress, desc="smrf shapes")
