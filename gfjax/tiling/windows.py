"""Raster windows: a raster built over the whole cloud, cut into buffered tiles, run in batches.

The raster counterpart of `tiles.split` -> `driver.run_batches` -> `mosaic`, for a method
whose per-tile program takes rasters already made over the whole cloud rather than points
(DMF's NGNEM, its layer index and valid cells: they come from voxels and a basal layer built
for the whole cloud, so a tile cannot rasterise its own points). The raster is cut into
square cores of `core_px` cells, each grown by `buffer_px` cells of context and clipped to
the raster (`raster_windows`); the windows run `max_batch` at a time through one program, every
batch full (`batches.filled`: one batch shape, one compile), and each window's core cells of
the outputs are pasted into whole-raster arrays (`run_windows`). A cell's value comes from the
one window whose core holds it, as a point's label does in `tiles.merge`.

Windows are in array indices of the raster (row 0 = its first row); a window's inputs sit in
the top-left corner of its padded tile. Host-side numpy around the caller's jitted program.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from gfjax.tiling.batches import filled

__all__ = ["Window", "raster_windows", "run_windows"]


class Window(NamedTuple):
    """One buffered window of a raster, in array indices `[start, stop)`.

    Attributes:
      rows, cols: the window: the core grown by the buffer, clipped to the raster.
      core_rows, core_cols: its core, whose cells it alone gives.
    """

    rows: tuple[int, int]
    cols: tuple[int, int]
    core_rows: tuple[int, int]
    core_cols: tuple[int, int]


def raster_windows(shape: tuple[int, int], *, core_px: int, buffer_px: int) -> list[Window]:
    """The windows of a raster of `shape` `(h, w)` cells: cores of `core_px` cells a side (the
    last of a row or column cut by the raster's edge) in row-major order, each with `buffer_px`
    cells of context around it. Every cell lies in exactly one core."""
    if core_px < 1 or buffer_px < 0:
        raise ValueError(f"core_px must be >= 1 and buffer_px >= 0, got {core_px}, {buffer_px}")
    h, w = shape
    out = []
    for r0 in range(0, h, core_px):
        for c0 in range(0, w, core_px):
            out.append(Window(rows=(max(0, r0 - buffer_px), min(h, r0 + core_px + buffer_px)),
                              cols=(max(0, c0 - buffer_px), min(w, c0 + core_px + buffer_px)),
                              core_rows=(r0, min(h, r0 + core_px)), core_cols=(c0, min(w, c0 + core_px))))
    return out


def run_windows(shape: tuple[int, int], windows: Sequence[Window], tile_of: Callable[[Window], tuple[np.ndarray, ...]],
                run_batch: Callable[..., Any], *, names: Mapping[str, Any], max_batch: int, progress: bool = False,
                desc: str = "raster tiles") -> tuple[dict[str, np.ndarray], list[tuple[Any, int]]]:
    """Run `run_batch` over `windows`, `max_batch` at a time, and paste each window's core.

    Args:
      shape: the whole raster `(h, w)`.
      windows: from `raster_windows`.
      tile_of: a window's inputs, each padded to one shape with the window's cells at its
        top-left (e.g. `(H, W)` rasters).
      run_batch: the program on the inputs stacked `(max_batch, ...)` (a batch of fewer windows
        is filled with copies of its last, whose outputs are not read) -> outputs whose fields
        `names` are `(max_batch, H, W)` rasters laid out as the inputs.
      names: the output fields pasted, name -> dtype of the whole-raster array.
      max_batch: windows per call.
      progress: show a progress bar over batches, labelled `desc`.

    Returns:
      `(rasters, outputs)`: name -> `(h, w)` array whose every cell comes from the window whose
      core holds it; and per batch `(run_batch's outputs, number of real windows)`, in order,
      for anything else the caller reads of them (only the first windows of each are real).
    """
    if max_batch < 1:
        raise ValueError(f"max_batch must be >= 1, got {max_batch}")
    rasters = {name: np.zeros(shape, dtype) for name, dtype in names.items()}
    outputs = []
    starts = range(0, len(windows), max_batch)
    if progress:
        from tqdm.auto import tqdm
        starts = tqdm(starts, desc=desc, unit="batch")
    for s in starts:
        group = windows[s:s + max_batch]
        tiles = [tile_of(window) for window in group]
        out = run_batch(*filled([np.stack(parts) for parts in zip(*tiles)], max_batch))
        outputs.append((out, len(group)))
        for i, window in enumerate(group):
            (r0, r1), (c0, c1) = window.core_rows, window.core_cols
            a, c = window.rows[0], window.cols[0]
            for name, whole in rasters.items():
                tile = np.asarray(getattr(out, name)[i])
                whole[r0:r1, c0:c1] = tile[r0 - a:r1 - a, c0 - c:c1 - c]
    return rasters, outputs
