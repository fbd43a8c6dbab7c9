"""Whole-cloud rasters pasted from the cores of tiles' rasters.

A tiled method's diagnostics (SMRF's and PMF's surfaces) are computed per tile window; each
point of the cloud's cell lattice takes its value from the one tile whose core holds it, as
each point takes its label (`tiles.merge`). Row 0 is north (docs/ARCHITECTURE.md); the tiles'
rasters come cropped to their own extent (`driver.run_batches`).

Host-side numpy.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from gfjax.tiling import tiles as tiles_lib

__all__ = ["Mosaic", "mosaic"]


class Mosaic(NamedTuple):
    """Whole-cloud rasters from tile cores (host numpy, row 0 = north).

    Attributes:
      rasters: name -> `(h, w)` raster over the cloud's cell lattice; float fields as float64
        (heights shifted to the cloud's vertical frame [m]), bool fields as bool.
      origin_m: float64 `(2,)`, x and y of the raster's south-west corner [m].
    """

    rasters: dict[str, np.ndarray]
    origin_m: np.ndarray


def mosaic(tiles: Sequence[tiles_lib.Tile], diagnostics: Sequence[tuple], *, names: Sequence[str],
           heights: Sequence[str] = (), cell_m: float) -> Mosaic:
    """Paste each tile's core cells of its cropped rasters into whole-cloud rasters.

    Args:
      tiles: from `tiles.split` (at least one).
      diagnostics: per tile, a NamedTuple of `tile.shape` rasters (row 0 = north), as
        `run_batches` returns them.
      names: the fields to mosaic.
      heights: those of `names` holding tile-local heights; the cloud's z origin is added [m].
      cell_m: the tiles' raster cell [m].

    Returns:
      `Mosaic`: rasters `(H, W)` over the bounding box of the cores, and its south-west corner;
      cells of no tile's core hold 0 and are never written, so a box that is mostly empty (a
      stray point kilometres away) costs memory only for its tiles' pages.
    """
    col0 = min(t.core_px[0] for t in tiles)
    row0 = min(t.core_px[1] for t in tiles)
    width = max(t.core_px[2] for t in tiles) - col0
    height = max(t.core_px[3] for t in tiles) - row0
    first = diagnostics[0]
    z0 = float(tiles[0].origin_m[2])
    out = {}
    for name in names:
        dtype = np.asarray(getattr(first, name)).dtype
        out[name] = np.zeros((height, width), np.float64 if np.issubdtype(dtype, np.floating) else dtype)
    for tile, diag in zip(tiles, diagnostics):
        c0, r0, c1, r1 = tile.core_px
        wc, wr = tile.window_px
        h = tile.shape[0]
        src_rows = slice(h - (r1 - wr), h - (r0 - wr))             # rows from the south -> north-up
        dst_rows = slice(height - (r1 - row0), height - (r0 - row0))
        for name in names:
            cells = getattr(diag, name)[src_rows, c0 - wc:c1 - wc]
            out[name][dst_rows, c0 - col0:c1 - col0] = cells + z0 if name in heights else cells
    origin = tiles[0].origin_m[:2] + (np.asarray([col0, row0]) - np.asarray(tiles[0].window_px)) * cell_m
    return Mosaic(rasters=out, origin_m=origin)
