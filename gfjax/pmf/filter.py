"""`gfjax.pmf.filter`: the progressive morphological filter (Zhang et al. 2003) on a whole cloud.

1. ZImin: the lowest point per cell, empty cells filled from the nearest non-empty cell;
2. for windows `w_k = 2 b^k + 1` cells (3, 5, 9, 17, 33 by default): open the surface with a
   square window of `w_k` cells; a point whose height above the opened surface is not below
   `dh_k = min(slope (w_k - w_{k-1}) c + dh0, dh_max)` is non-ground; the opened surface
   becomes the surface;
3. the points that passed every window are ground.

The cloud is cut into buffered tiles (`gfjax.io.tiles`); each batch of equal-shape tiles runs
through one jitted, vmapped call of `programs.classify_batch` (`gfjax.io.tiled` drives the tiles
and mosaics the tile cores).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from gfjax.io import tiled
from gfjax.io.cloud import CloudView
from gfjax.pmf import programs
from gfjax.pmf.config import MAX_BATCH, Config, Params
from gfjax.result import Result

__all__ = ["filter", "warm", "PMFDiagnostics", "MAX_BATCH"]



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


def filter(cloud: CloudView, *, config: Config | None = None, params: Params | None = None,
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
      `diagnostics` a `PMFDiagnostics` (None for a cloud with no usable point, and for one whose
      groups of points far apart were moved side by side: `gfjax.io.tiled.laid_out`).
    """
    config, params, use = tiled.checked_options(cloud, config, params, returns, config_type=Config,
                                                params_type=Params, package="gfjax.pmf")
    xyz_m, layout = tiled.laid_out(cloud, use, config, reach_m=config.buffer_m,
                                   keep_frame=cloud.frame is not None)
    run = tiled.classify_cloud(xyz_m, use, programs.classify_batch, params, config, max_batch=MAX_BATCH,
                               frame=cloud.frame, progress=progress, desc="pmf tiles")
    if not run.tiles or layout is not None:     # moved groups: the rasters would map the layout, not the cloud
        return Result(ground=run.ground, diagnostics=None)
    cores = tiled.mosaic(run.tiles, run.diagnostics, names=("zimin", "surface", "empty"),
                         heights=("zimin", "surface"), cell_m=config.cell_m)
    return Result(ground=run.ground, diagnostics=PMFDiagnostics(
        **cores.rasters, origin_m=cores.origin_m, cell_m=config.cell_m, windows_px=config.windows_px,
        n_tiles=len(run.tiles)))


def warm(config: Config | None = None, params: Params | None = None, *, progress: bool = False) -> int:
    """Prepare the programs `filter` runs on a file of one tile of any size (`tiled.warm`):
    later first runs load them instead of compiling. Returns the number of shapes prepared."""
    config, params = config or Config(), params or Params()
    return tiled.warm(programs.classify_batch, params, config, progress=progress, desc="pmf shapes")
