"""A large window's points run through a tiled method's point programs a chunk at a time.

A tiled method (SMRF, PMF) runs three programs per batch of windows: the lowest point per
cell (a reduction over the points), the raster stages, and the per-point test. The point
programs' temporaries grow with the points they are given, so a window of millions of points
(a survey's full 500 m tile) runs them over `POINT_CHUNK` points at a time: the lowest point
per cell is the minimum over the chunks' minima, and each point's label depends only on that
point and the rasters, so the labels are exactly those of one call over every point. Memory
then follows the chunk, not the window, and one program per raster shape serves every window
above the chunk (`buckets.tile_capacity` pads them to whole chunks).

Host-side numpy around the compiled programs.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from gfjax._types import Host
from gfjax.tiling.buckets import POINT_CHUNK
from gfjax.tiling.tiles import WindowRows

__all__ = ["POINT_CHUNK", "chunked", "lowest", "labels"]


def chunked(capacity: int) -> bool:
    """Whether a point axis of `capacity` slots runs a chunk at a time (`lowest`, `labels`)."""
    return _slices(capacity) is not None


def _slices(capacity: int) -> list[slice] | None:
    """The chunks of a point axis of `capacity` slots, or None for one call: it fits one, or it
    is no whole number of chunks (a capacity not of `buckets.tile_capacity`: tuning's)."""
    if capacity <= POINT_CHUNK or capacity % POINT_CHUNK:
        return None
    return [slice(start, start + POINT_CHUNK) for start in range(0, capacity, POINT_CHUNK)]


def _rows(xyz, part: slice):
    """Rows `part` of points `xyz` `(..., m, 3)`, zeros where they run past its `m` rows: a
    lone window's points are passed unpadded (`batches.TileBatch`), padded a chunk at a time;
    a `WindowRows` `(m, 3)` is a batch of one, made here a chunk at a time."""
    m = xyz.shape[-2]
    own = slice(min(part.start, m), min(part.stop, m))
    rows = xyz.rows(own)[None] if isinstance(xyz, WindowRows) else xyz[..., own, :]
    if own.stop - own.start == part.stop - part.start:
        return rows
    out = np.zeros((*rows.shape[:-2], part.stop - part.start, rows.shape[-1]), rows.dtype)
    out[..., :own.stop - own.start, :] = rows
    return out


def lowest(program: Callable, xyz, valid) -> tuple:
    """`program(xyz, valid) -> (z_min, filled)`, the lowest z per cell (+inf where empty) and the
    cells holding a point, `(..., h, w)`, over points `xyz` `(..., cap, 3)`, `valid` `(..., cap)`:
    one call, or the minimum and union over chunks of `POINT_CHUNK` points (host numpy; then
    `xyz` may hold fewer rows than `valid`, the rest padding)."""
    parts = _slices(valid.shape[-1])
    if parts is None:
        return program(xyz, valid)
    z_min = filled = None
    for part in parts:
        z, f = program(_rows(xyz, part), valid[..., part])
        if z_min is None:
            z_min, filled = np.array(z), np.array(f)
        else:
            np.minimum(z_min, np.asarray(z), out=z_min)
            filled |= np.asarray(f)
    return z_min, filled


def labels(program: Callable, xyz, valid, *rasters) -> Host:
    """`program(xyz, valid, *rasters) -> ground` `(..., cap)` bool, one call, or one call per
    chunk of `POINT_CHUNK` points joined (host numpy; `xyz` as `lowest`'s); `rasters`: the program's other arguments,
    the same for every chunk."""
    parts = _slices(valid.shape[-1])
    if parts is None:
        return program(xyz, valid, *rasters)
    out = np.empty(valid.shape, bool)
    for part in parts:
        out[..., part] = np.asarray(program(_rows(xyz, part), valid[..., part], *rasters))
    return out
