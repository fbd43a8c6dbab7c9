"""Tiles padded into fixed-shape batches for `jax.vmap`.

Tiles (`tiles.split`) of similar raster shape and point count are stacked into `TileBatch`es:
points padded to a capacity with a `valid` mask, rasters to one shape, each tile's own extent
in the south-west corner of the padded raster (row 0 = north, docs/ARCHITECTURE.md). The sizes
come from `buckets`: a filter pads to *canonical* shapes (`canonical_sides`, point capacities
in powers of 4, batches of one tile or of `max_batch`), tuning to tighter buckets; windows of
a few cells (`small_batches`) share full batches of small sides.

Host-side numpy; JAX receives `TileBatch.xyz` (float32 local metres).
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np

from gfjax.tiling import buckets, chunks
from gfjax.tiling.buckets import SHAPE_QUANTUM_PX, SMALL_SIDES_PX, SMALLEST_SIDE_PX
from gfjax.tiling.tiles import Tile, WindowRows

__all__ = ["TileBatch", "batches", "small_batches", "filled"]


class TileBatch(NamedTuple):
    """Tiles padded to one capacity and one raster shape, stacked for `jax.vmap`.

    Attributes:
      xyz: float32 `(b, cap, 3)` local metres (zeros on padding); for a lone window whose
        points run a chunk at a time (`batches` with `sides`, `chunks.chunked`), its own
        `local_xyz` instead, not copied: `(1, m, 3)`, or its `WindowRows` `(m, 3)` (a batch of
        one, made a chunk at a time); the rows from `m` to `cap` are padding (`chunks.lowest`
        pads them a chunk at a time).
      valid: bool `(b, cap)` real points.
      hw: int32 `(b, 2)` each tile's own raster extent (rows, cols) inside `shape`.
      shape: the padded raster `(h, w)` (static for jit).
      tiles: the `b` tiles, in batch order.
    """

    xyz: np.ndarray
    valid: np.ndarray
    hw: np.ndarray
    shape: tuple[int, int]
    tiles: tuple[Tile, ...]


def _canonical_shape(shape: tuple[int, int], sides: Sequence[int]) -> tuple[int, int]:
    square = buckets.canonical_square(shape, sides)
    if square is None:
        raise ValueError(f"a window of {shape} cells is larger than the canonical sides {tuple(sides)}")
    return square


def _pad(tiles: Sequence[Tile], capacity: int, shape: tuple[int, int], *, share: bool = False) -> TileBatch:
    b = len(tiles)
    # a survey's window holds millions of points: a second copy of them is the largest array of its run
    share = share and b == 1 and chunks.chunked(capacity)
    if share and isinstance(tiles[0].local_xyz, WindowRows):
        xyz = tiles[0].local_xyz                  # made a chunk at a time (`chunks.lowest`)
    elif share and tiles[0].local_xyz.flags.c_contiguous:
        xyz = tiles[0].local_xyz[None]
    else:
        share, xyz = False, np.zeros((b, capacity, 3), np.float32)
    valid = np.zeros((b, capacity), bool)
    hw = np.zeros((b, 2), np.int32)
    for i, tile in enumerate(tiles):
        if tile.n_points > capacity or tile.shape[0] > shape[0] or tile.shape[1] > shape[1]:
            raise ValueError(f"tile {tile.key} ({tile.n_points} points, {tile.shape}) does not fit "
                             f"capacity {capacity} / shape {shape}")
        if not share:
            xyz[i, :tile.n_points] = np.asarray(tile.local_xyz)
        valid[i, :tile.n_points] = True
        hw[i] = tile.shape
    return TileBatch(xyz=xyz, valid=valid, hw=hw, shape=tuple(shape), tiles=tuple(tiles))


def batches(tiles: Sequence[Tile], *, max_batch: int = 8, capacity: int | None = None,
            shape: tuple[int, int] | None = None, quantum_px: int = SHAPE_QUANTUM_PX,
            sides: Sequence[int] | None = None) -> Iterator[TileBatch]:
    """Group tiles by raster shape, and pad each group into batches of similar point counts.

    Args:
      tiles: from `tiles.split`.
      max_batch: most tiles per batch (bounds memory).
      capacity: force one point capacity (default: the bucket of the largest tile of a batch).
      shape: force one raster shape (default: each tile's shape bucket).
      quantum_px: shape bucket step in cells.
      sides: canonical square sides (`buckets.canonical_sides`): each tile is padded to the
        smallest that holds it, capacities are `buckets.tile_capacity`, and a group runs in
        batches of exactly `max_batch` tiles, then one tile at a time, so only canonical shapes
        compile. None: shapes rounded to `quantum_px`, capacities `buckets.capacity_bucket`,
        batches of up to
        `max_batch` (fewest calls, for a fixed set of samples such as tuning's).

    Yields:
      `TileBatch`es; every tile appears in exactly one.
    """
    if max_batch < 1:
        raise ValueError(f"max_batch must be >= 1, got {max_batch}")
    groups: dict[tuple[int, int], list[Tile]] = {}
    for tile in tiles:
        if shape is not None:
            key = tuple(shape)
        elif sides is not None:
            key = _canonical_shape(tile.shape, sides)
        else:
            key = buckets.shape_bucket(tile.shape, quantum_px=quantum_px)
        groups.setdefault(key, []).append(tile)
    bucket = buckets.capacity_bucket if sides is None else buckets.tile_capacity
    for group_shape, members in sorted(groups.items()):
        members = sorted(members, key=lambda t: t.n_points)
        if sides is None:
            chunks = [members[i:i + max_batch] for i in range(0, len(members), max_batch)]
        else:
            full = len(members) - len(members) % max_batch
            chunks = [members[i:i + max_batch] for i in range(0, full, max_batch)] + [[t] for t in members[full:]]
        for chunk in chunks:
            cap = capacity if capacity is not None else bucket(max(t.n_points for t in chunk))
            yield _pad(chunk, cap, group_shape, share=sides is not None)


def small_batches(tiles: Sequence[Tile], *, max_batch: int = 8) -> Iterator[TileBatch]:
    """Batches of windows of at most `SMALL_SIDES_PX[-1]` cells a side (a cloud of small groups
    far apart: `driver.classify_groups`), each padded to the smallest of `SMALL_SIDES_PX` holding it.

    A batch holds the cells of `max_batch` windows of the smallest canonical side, so more
    tiles when they are smaller (2,048 tiles of 8 x 8 cells for `max_batch` 8), and every batch
    is full: the last one is padded with copies of its last tile, whose outputs are not read
    (`TileBatch.tiles` holds the real ones), so each side compiles one program and a lone tile
    none of its own (`filled`). Capacities are `buckets.capacity_bucket`s: a few points need no
    16,384 slots.
    """
    if max_batch < 1:
        raise ValueError(f"max_batch must be >= 1, got {max_batch}")
    groups: dict[tuple[int, int], list[Tile]] = {}
    for tile in tiles:
        groups.setdefault(_canonical_shape(tile.shape, SMALL_SIDES_PX), []).append(tile)
    for shape, members in sorted(groups.items()):
        size = max_batch * (SMALLEST_SIDE_PX // shape[0]) ** 2
        members = sorted(members, key=lambda t: t.n_points)
        for start in range(0, len(members), size):
            chunk = members[start:start + size]
            batch = _pad(chunk, buckets.capacity_bucket(max(t.n_points for t in chunk)), shape)
            xyz, valid, hw = filled((batch.xyz, batch.valid, batch.hw), size)
            yield batch._replace(xyz=xyz, valid=valid, hw=hw)


def filled(arrays: Sequence[np.ndarray], size: int) -> list[np.ndarray]:
    """Batches `(b, ...)` each grown to `size` rows with copies of their last row, whose outputs
    are not read: every call of a program gets one batch shape, so it compiles once."""
    return [a if len(a) == size else np.concatenate([a, np.repeat(a[-1:], size - len(a), axis=0)]) for a in arrays]
