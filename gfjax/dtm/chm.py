"""Canopy height model: per cell, the highest point's height above the ground.

The forest user's first raster, as lidR's `rasterize_canopy(p2r())` and LAStools' `lasgrid
-highest` on normalised heights make it: each point's height over the ground TIN
(`gfjax.dtm.hag`), the highest of each cell, on the DTM's lattice (cell edges on whole
multiples of the cell, so a CHM and a DTM of one cell size lie on each other). Heights below
the ground (a point under the TIN between ground points) count as 0; a cell without a point is
nodata. Noise and withheld points are left out (`cloud.ignored`).
"""
from __future__ import annotations

import numpy as np

from gfjax.dtm.build import DTM, check_grid, check_options, checked_ground, snapped_grid
from gfjax.dtm.geotiff import NODATA, cloud_rasterio_crs
from gfjax.dtm.hag import height_above_ground

__all__ = ["chm"]


def chm(cloud, ground, *, cell_m: float = 1.0, context_xyz: np.ndarray | None = None) -> DTM:
    """The canopy height model of `cloud` over its `ground` points.

    Args:
      cloud: the point cloud; coordinates in file units (never converted).
      ground: bool `(n,)`, the points that make the terrain (`cloud.classification == 2`, a
        filter's `Result.ground`).
      cell_m: cell size in metres (`cell_m / cloud.horizontal_unit_m` file units).
      context_xyz: ground points around the cloud, float64 `(m, 3)` in its file units (a survey
        file's neighbours, as `gfjax.dtm.build` takes them): they enter the ground TIN, so the
        heights at the cloud's borders are those one CHM of the whole survey would give.

    Returns:
      A raster of the `DTM` class: `z` float64 `(h, w)` heights in the file's vertical unit
      (nodata -9999 in empty cells), `count` int32 `(h, w)` points per cell.

    Raises:
      InputError: a bad cell, a `ground` of the wrong shape, no ground point, or a grid over
        the memory budget; the message names the file.
    """
    name = cloud.name
    cell_m, _ = check_options(name, cell_m=cell_m)
    ground = checked_ground(cloud, ground, "a CHM")
    cell = cell_m / cloud.horizontal_unit_m
    used = ~np.asarray(cloud.ignored, bool) | ground
    xyz = cloud.xyz[used]
    col0, row_top, h, w = snapped_grid(xyz[:, :2], cell)
    check_grid(name, h, w, cell_m, "a CHM")
    context = np.empty((0, 3)) if context_xyz is None else np.asarray(context_xyz, np.float64).reshape(-1, 3)
    height = np.maximum(height_above_ground(np.concatenate([xyz, context]),
                                            np.concatenate([ground[used], np.ones(len(context), bool)]))[:len(xyz)],
                        0.0)
    col = np.floor(xyz[:, 0] / cell).astype(np.int64) - col0          # the DTM's floors
    row = (row_top - 1) - np.floor(xyz[:, 1] / cell).astype(np.int64)
    flat = row * w + col
    top = np.full(h * w, -np.inf)
    np.maximum.at(top, flat, height)
    count = np.bincount(flat, minlength=h * w).reshape(h, w).astype(np.int32)
    z = np.where(np.isfinite(top), top, NODATA).reshape(h, w)
    return DTM(z=z, count=count, origin=(float(col0 * cell), float(row_top * cell)), cell=float(cell),
               crs=cloud_rasterio_crs(cloud), horizontal_unit_m=cloud.horizontal_unit_m,
               vertical_unit_m=cloud.vertical_unit_m)
