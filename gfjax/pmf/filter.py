"""`gfjax.pmf.filter`: the progressive morphological filter (Zhang et al. 2003) on a whole cloud.

1. ZImin: the lowest point per cell, empty cells filled from the nearest non-empty cell;
2. for windows `w_k = 2 b^k + 1` cells (3, 5, 9, 17, 33 by default): open the surface with a
   square window of `w_k` cells; a point whose height above the opened surface is not below
   `dh_k = min(slope (w_k - w_{k-1}) c + dh0, dh_max)` is non-ground; the opened surface
   becomes the surface;
3. the points that passed every window are ground.

The cloud is cut into buffered tiles (`gfjax.tiling.tiles`); each batch of equal-shape tiles runs
through one jitted, vmapped call of `programs.classify_batch` (`gfjax.tiling.driver` drives the tiles
and mosaics the tile cores).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax import adaptive, cache
from gfjax.io.cloud import CloudView
from gfjax.pmf import programs
from gfjax.pmf.config import HIDES_LOW_OUTLIERS, MAX_BATCH, Config, Params, adapt
from gfjax.result import Result
from gfjax.tiling import driver
from gfjax.tiling.tiles import Tiling

__all__ = ["filter", "warm", "Diagnostics", "MAX_BATCH"]



class Diagnostics(NamedTuple):
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


@cache.persistent
@adaptive.follows(adapt, Config, Params, hides_low_outliers=HIDES_LOW_OUTLIERS)
def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,
           returns: str = "all", progress: bool = False, tiling: Tiling | None = None) -> Result:  # noqa: A001 (the package API name)
    """Classify a cloud's ground points with PMF (Zhang et al. 2003).

    Args:
      cloud: the point cloud (any units; filtered in metres).
      config: static settings (default: cell 1 m, max window 33 m, exponential windows, b = 2).
      params: thresholds (default: slope 1, initial distance 0.15 m, max distance 2.5 m).
      returns: "all" or "last": which returns are filtered.
      progress: show a progress bar over tile batches.
      tiling: how the cloud is cut into buffered tiles (default `Tiling()`: 500 m cores,
        50 m buffers; `gfjax.tiling.tiles.Tiling`).

    Returns:
      `Result(ground, diagnostics)`: `ground` bool `(n,)`, False for ignored points;
      `diagnostics` a `Diagnostics` (None for a cloud with no usable point, and for one whose
      groups of points far apart were filtered one by one: `gfjax.tiling.driver.classify_groups`).
    """
    done = driver.filter_cloud(cloud, config, params, returns, tiling=tiling, config_type=Config, params_type=Params,
                              package="gfjax.pmf", classify_batch=programs.classify_batch, max_batch=MAX_BATCH,
                              rasters=("zimin", "surface", "empty"), heights=("zimin", "surface"), progress=progress)
    if done.cores is None:
        return Result(ground=done.ground, diagnostics=None)
    return Result(ground=done.ground, diagnostics=Diagnostics(
        **done.cores.rasters, origin_m=done.cores.origin_m, cell_m=done.config.cell_m,
        windows_px=done.config.windows_px, n_tiles=done.n_tiles))


@cache.persistent
def warm(config: Config | None = None, params: Params | None = None, *, progress: bool = False,
         tiling: Tiling | None = None) -> int:
    """Prepare the programs `filter` runs on a file of one tile of any size (`driver.warm`):
    later first runs load them instead of compiling. Returns the number of shapes prepared."""
    config, params = config or Config(), params or Params()
    return driver.warm(programs.classify_batch, params, config, tiling=tiling, progress=progress, desc="pmf shapes")
