"""Buffered square tiles, padded into fixed-shape batches for `jax.vmap`, and the label merge.

A cloud's metre coordinates are cut into square tile *cores* of `tile_size_m` on a lattice
anchored at the minimum corner of the points used, or at the corner of a given `Frame` (a
survey's: then a point gets the same tile, cells and local coordinates whichever file of the
survey it is filtered with); each point belongs to exactly one core.
A tile holds its core's points plus the points within `buffer_m` around it (its *window*),
so a local method sees context across the seam; only the core points' labels are kept when
merging (SPEC section 1, "Tiles").

Windows are snapped to the raster lattice of `cell_m` anchored at the same corner, so a
point falls in the same raster cell whichever tile holds it (the float32 local coordinates
are clamped into their float64 cell), and they are clipped to the cloud's extent. A window
is cut to its core points' box grown by the buffer when that is at most a quarter of it
(`CROP_SAVING`): a core of a few points keeps the context a buffer gives them, and a cloud
spread thin over a large box rasterises about its points, not its tiles. For
`vmap`, tiles are padded to a few *capacity buckets* (points) and *shape buckets* (raster
rows/columns) and carry `valid` masks; the tile's own extent sits in the south-west corner
of the padded raster (row 0 = north, docs/ARCHITECTURE.md). A filter pads to *canonical*
shapes (`canonical_sides`: a handful of square sides fixed by the tiling, point capacities in
powers of 4, batches of one tile or of `max_batch`), so a machine compiles each method's
programs a few times in its life, not once per input size, and `gfjax warmup` can compile
them all ahead.

Host-side numpy (float64); JAX receives `TileBatch.xyz` (float32 local metres).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np

from gfjax import limits
from gfjax.errors import SettingError
from gfjax.io import columns
from gfjax.limits import Range

__all__ = ["Tiling", "Lattice", "RANGES", "Frame", "Tile", "TileBatch", "split", "small_batches", "capacity_bucket", "shape_bucket", "canonical_sides",
           "canonical_capacities", "canonical_capacity", "batches", "merge"]

MIN_CAPACITY = 256
SHAPE_QUANTUM_PX = 64
SMALLEST_SIDE_PX = 128        # the smallest canonical raster side (`canonical_sides`)
SMALL_SIDES_PX = (8, 16, 32, 64)   # the sides of `small_batches`, below the canonical ones
CANONICAL_MIN_CAPACITY = 1 << 14
CANONICAL_MAX_CAPACITY = 1 << 22   # the largest capacity `gfjax warmup` compiles ahead
CROP_SAVING = 4.0             # a window shrinks to its core points' box + buffer when that is this many times smaller
FEW_CORES = 4                 # `split` finds the points of at most this many named tiles by masks


# The valid range of each tiling option (`Tiling`; `--tile-size`, `--buffer`).
RANGES: dict[str, Range] = {
    "tile_size_m": Range(0, 100_000, low_open=True, unit="m", extra=">= the method's cell"),
    "buffer_m": Range(0, 10_000, unit="m"),
}


class Lattice(NamedTuple):
    """A tiling at a method's raster cell: the three numbers `split` and `canonical_sides` take.

    Attributes:
      tile_size_m: side of a tile core [m].
      buffer_m: context around each core [m].
      cell_m: the raster cell the windows snap to [m].
    """

    tile_size_m: float
    buffer_m: float
    cell_m: float


@dataclasses.dataclass(frozen=True)
class Tiling:
    """How a cloud is cut into buffered square tiles: an option of the driver that runs a
    method, never of the method's stages (a tile's raster shape is the only thing they see).

    SMRF and PMF cut the cloud, DMF its NGNEM raster; whatever the tiling, a point's label
    comes from the tile whose core holds it, with `buffer_m` of context around the core.

    Attributes:
      tile_size_m: side of a tile core [m] (`--tile-size`).
      buffer_m: context kept around each core [m] (`--buffer`; rounded out to whole cells).
    """

    tile_size_m: float = 500.0
    buffer_m: float = 50.0

    def __post_init__(self) -> None:
        limits.check_fields(self, RANGES)

    def lattice(self, cell_m: float) -> Lattice:
        """This tiling at a raster cell of `cell_m` [m]; a core must hold at least one cell."""
        if self.tile_size_m < cell_m:
            raise SettingError(f"tile_size_m must be >= the cell ({cell_m:g} m), got {self.tile_size_m!r}",
                               "tile_size_m", "cell_m")
        return Lattice(float(self.tile_size_m), float(self.buffer_m), float(cell_m))


class Frame(NamedTuple):
    """The box a tiling is laid on: its lattice starts at `origin_m` and windows stop at `upper_m`.

    Attributes:
      origin_m: float64 `(3,)` minimum x, y, z of the points filtered [m].
      upper_m: float64 `(2,)` maximum x, y [m].
      cores: the keys `(col, row)` of the only tiles `split` makes (None: every tile holding a
        point): a survey filters each tile of its lattice once, from a window of its points
        that also holds parts of the neighbouring tiles (`gfjax.survey.lattice`).
    """

    origin_m: np.ndarray
    upper_m: np.ndarray
    cores: frozenset[tuple[int, int]] | None = None

    @classmethod
    def of(cls, xyz_m: np.ndarray) -> Frame:
        """The frame of points `(n, 3)` (n >= 1): their bounding box."""
        xyz_m = np.asarray(xyz_m, np.float64)
        return cls(columns.lows(xyz_m), columns.highs(xyz_m[:, :2]))

    def union(self, other: Frame) -> Frame:
        return Frame(np.minimum(self.origin_m, other.origin_m), np.maximum(self.upper_m, other.upper_m))

    def only(self, cores) -> Frame:
        """This frame, with `split` making only the tiles of the keys `cores` `(col, row)`."""
        return self._replace(cores=frozenset((int(c), int(r)) for c, r in cores))

    def snap(self, corner_m: np.ndarray, cell_m: float) -> np.ndarray:
        """The corner of the cell of this frame's lattice (cubes of `cell_m` from `origin_m`)
        that holds `corner_m` (float64 `(3,)` [m]): a window of a survey anchored there grids
        its points into the cells the whole survey in one file would use."""
        origin = np.asarray(self.origin_m, np.float64)
        return origin + np.floor((np.asarray(corner_m, np.float64) - origin) / cell_m) * cell_m


@dataclasses.dataclass(frozen=True, eq=False)
class Tile:
    """One buffered tile.

    Attributes:
      key: `(col, row)` of the tile core in the tiling (row 0 = southernmost).
      origin_m: float64 `(3,)`: the window's south-west corner (x, y) and the cloud's z
        origin [m]; local coordinates are `xyz_m - origin_m`.
      shape: raster `(h, w)` of the window at `cell_m` (its own extent, before padding).
      index: int64 `(m,)` indices into the cloud of the window's points.
      core: bool `(m,)` which of them lie in the tile core.
      local_xyz: float32 `(m, 3)` local metres of those points, each clamped into the raster
        cell its float64 coordinates fall in.
      window_px: `(col, row)` of the window's south-west cell in the cloud's cell lattice
        (rows counted from the south).
      core_px: `(col0, row0, col1, row1)`: the core's cells `[col0, col1) x [row0, row1)` in
        the same lattice, clipped to the window (so to the cloud's extent).
    """

    key: tuple[int, int]
    origin_m: np.ndarray
    shape: tuple[int, int]
    index: np.ndarray
    core: np.ndarray
    local_xyz: np.ndarray
    window_px: tuple[int, int] = (0, 0)
    core_px: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def n_points(self) -> int:
        return int(self.index.shape[0])


class TileBatch(NamedTuple):
    """Tiles padded to one capacity and one raster shape, stacked for `jax.vmap`.

    Attributes:
      xyz: float32 `(b, cap, 3)` local metres (zeros on padding).
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


def _check(tile_size_m: float, buffer_m: float, cell_m: float) -> None:
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if not (math.isfinite(tile_size_m) and tile_size_m >= cell_m):
        raise ValueError(f"tile_size_m must be >= cell_m ({cell_m}), got {tile_size_m}")
    if not (math.isfinite(buffer_m) and buffer_m >= 0):
        raise ValueError(f"buffer_m must be >= 0, got {buffer_m}")


def _clamp_into_cells(local: np.ndarray, cell: np.ndarray, cell_m: float) -> np.ndarray:
    """Float32 coordinates that stay inside the cell `cell` (int) their float64 value is in."""
    out = local.astype(np.float32)
    # Only a value within a few float32 steps of its cell's edge can round out of it; the
    # others are left as they are (the clip would keep them), so the clip runs on few rows.
    largest = max(float(np.abs(columns.lows(local)).max()), float(np.abs(columns.highs(local)).max())) \
        if len(local) else 0.0
    margin = 4.0 * float(np.spacing(np.float32(largest + cell_m)))
    offset = cell * cell_m
    np.subtract(local, offset, out=offset)
    near = np.flatnonzero(columns.some((offset < margin) | (offset > cell_m - margin)))
    if near.size:
        c = cell[near]
        lo = (c * cell_m).astype(np.float32)
        hi = np.nextafter(((c + 1) * cell_m).astype(np.float32), np.float32(-np.inf))
        lo = np.where(np.floor(lo / np.float32(cell_m)) < c, np.nextafter(lo, np.float32(np.inf)), lo)
        out[near] = np.clip(out[near], lo, np.maximum(lo, hi))
    return out


def _cropped(core_cells: np.ndarray, reach_px: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The window `[lo, hi)` (cells) cut to the box of its core points' cells `(m, 2)` grown
    by `reach_px`, when that box is at most `1 / CROP_SAVING` of it: a core of a few points
    in a mostly empty box rasterises their surroundings, not a whole tile."""
    box_lo = np.maximum(columns.lows(core_cells) - reach_px, lo)
    box_hi = np.minimum(columns.highs(core_cells) + 1 + reach_px, hi)
    if np.prod((box_hi - box_lo).astype(np.float64)) * CROP_SAVING > np.prod((hi - lo).astype(np.float64)):
        return lo, hi
    return box_lo, box_hi


def split(xyz_m: np.ndarray, *, tile_size_m: float = 500.0, buffer_m: float = 50.0,
          cell_m: float = 1.0, use: np.ndarray | None = None, frame: Frame | None = None) -> list[Tile]:
    """Cut a cloud into buffered square tiles.

    Args:
      xyz_m: float64 `(n, 3)` coordinates [m].
      tile_size_m: side of a tile core [m].
      buffer_m: context kept around each core [m] (rounded out to whole cells).
      cell_m: raster cell the windows snap to [m].
      use: bool `(n,)` points to tile (default all); the others belong to no tile.
      frame: the lattice's box (default: the used points' own, `Frame.of`); every used point
        must lie in it. Its `cores`, when set, are the only tiles made.

    Returns:
      Non-empty tiles in row-major order of their keys. Every used point is in exactly one
      core (of a tile made, with `frame.cores`); a tile's window holds the used points within
      `buffer_m` of its core.
    """
    _check(tile_size_m, buffer_m, cell_m)
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    if xyz_m.ndim != 2 or xyz_m.shape[1] != 3:
        raise ValueError(f"xyz_m must have shape (n, 3), got {xyz_m.shape}")
    use = np.ones(len(xyz_m), bool) if use is None else np.asarray(use, dtype=bool)
    if use.shape != (len(xyz_m),):
        raise ValueError(f"use must have shape ({len(xyz_m)},), got {use.shape}")
    every_used = bool(use.all())
    if not np.isfinite(xyz_m if every_used else xyz_m[use]).all():
        raise ValueError("xyz_m holds non-finite coordinates")
    used = np.flatnonzero(use)
    if used.size == 0:
        return []
    rel = xyz_m.copy() if every_used else xyz_m[used]            # a copy: made relative in place
    frame = Frame.of(rel) if frame is None else frame
    origin = np.asarray(frame.origin_m, np.float64)
    if np.any(columns.lows(rel) < origin) or np.any(columns.highs(rel[:, :2]) > np.asarray(frame.upper_m)):
        raise ValueError("points lie outside the tiling frame")
    rel -= origin                                                 # float64, >= 0
    # Few temporaries of n rows: a window holds millions of points, and fresh pages cost more
    # than the arithmetic on them.
    scaled = rel[:, :2] / cell_m
    cell = np.floor(scaled, out=scaled).astype(np.int64)         # global (col, row-from-south)
    np.divide(rel[:, :2], tile_size_m, out=scaled)
    core = np.floor(scaled, out=scaled).astype(np.int64)
    del scaled
    extent_px = np.floor((np.asarray(frame.upper_m) - origin[:2]) / cell_m).astype(np.int64) + 1
    core_px = tile_size_m / cell_m
    buffer_px = math.ceil(buffer_m / cell_m - 1e-9)

    reach = max(1, math.ceil((buffer_px + 1) * cell_m / tile_size_m))   # neighbour cores a window reaches
    if frame.cores is not None and len(frame.cores) <= FEW_CORES:
        # a survey's window made for one tile: a mask per tile, no sort of the window's points
        wanted = [k for k in sorted(frame.cores, key=lambda k: (k[1], k[0]))
                  if np.any((core[:, 0] == k[0]) & (core[:, 1] == k[1]))]

        def candidates_of(ti: int, tj: int) -> np.ndarray:
            return np.flatnonzero((np.abs(core[:, 0] - ti) <= reach) & (np.abs(core[:, 1] - tj) <= reach))
    else:
        by_core: dict[tuple[int, int], np.ndarray] = {}
        rows = int(core[:, 1].max()) + 1
        packed = core[:, 0] * rows + core[:, 1]              # by col, then row; one int64 sorts fast
        if packed.min() == packed.max():                     # one core (a small file): no sort
            by_core[(int(core[0, 0]), int(core[0, 1]))] = np.arange(len(packed))
        else:
            order = np.argsort(packed, kind="stable")
            keys, starts = np.unique(packed[order], return_index=True)
            for key, chunk in zip(keys, np.split(order, starts[1:])):
                by_core[(int(key // rows), int(key % rows))] = chunk
        wanted = sorted(by_core, key=lambda k: (k[1], k[0]))
        if frame.cores is not None:
            wanted = [key for key in wanted if key in frame.cores]

        def candidates_of(ti: int, tj: int) -> np.ndarray:
            parts = [by_core[key] for dj in range(-reach, reach + 1) for di in range(-reach, reach + 1)
                     if (key := (ti + di, tj + dj)) in by_core]
            if len(parts) == 1:
                return parts[0]                              # sorted already
            found = np.concatenate(parts)
            found.sort()
            return found

    tiles = []
    for (ti, tj) in wanted:
        k = np.array([ti, tj])
        candidates = candidates_of(ti, tj)
        core_lo = np.floor(k * core_px).astype(np.int64)
        core_hi = np.minimum(np.ceil((k + 1) * core_px).astype(np.int64), extent_px)
        lo = np.maximum(core_lo - buffer_px, 0)
        hi = np.minimum(core_hi + buffer_px, extent_px)
        # A window of every point (a small file, a survey's window) gathers no copies: the
        # copies of millions of rows cost more than the arithmetic on them.
        every = len(candidates) == len(rel)              # candidates are sorted and distinct
        c = cell if every else cell[candidates]
        cc = core if every else core[candidates]
        of_core = (cc[:, 0] == ti) & (cc[:, 1] == tj)
        lo, hi = _cropped(c if every and of_core.all() else c[of_core], buffer_px, lo, hi)
        inside = (c[:, 0] >= lo[0]) & (c[:, 0] < hi[0]) & (c[:, 1] >= lo[1]) & (c[:, 1] < hi[1])
        every = every and bool(inside.all())
        members, in_core = (candidates, of_core) if every else (candidates[inside], of_core[inside])
        shift = np.concatenate([lo * cell_m, [0.0]])
        if every and len(wanted) == 1:                   # the last use of `cell` and `rel`
            local_cell, local = cell, rel
            local_cell -= lo[None, :]
            local -= shift[None, :]
        else:
            local_cell = (cell if every else cell[members]) - lo[None, :]
            local = (rel if every else rel[members]) - shift[None, :]
        local32 = local.astype(np.float32)
        local32[:, :2] = _clamp_into_cells(local[:, :2], local_cell, cell_m)
        shape = (int(hi[1] - lo[1]), int(hi[0] - lo[0]))
        core_lo, core_hi = np.maximum(core_lo, lo), np.minimum(core_hi, hi)
        tiles.append(Tile(key=(ti, tj), origin_m=origin + shift, shape=shape, index=used[members],
                          core=in_core, local_xyz=local32, window_px=(int(lo[0]), int(lo[1])),
                          core_px=(int(core_lo[0]), int(core_lo[1]), int(core_hi[0]), int(core_hi[1]))))
    return tiles


def capacity_bucket(n: int, *, minimum: int = MIN_CAPACITY) -> int:
    """Smallest of `minimum * {1, 1.5} * 2^k` holding `n` points (few shapes ever compile)."""
    size = minimum
    while True:
        if n <= size:
            return size
        if n <= size * 3 // 2:
            return size * 3 // 2
        size *= 2


def shape_bucket(shape: tuple[int, int], *, quantum_px: int = SHAPE_QUANTUM_PX) -> tuple[int, int]:
    """Raster shape rounded up to a multiple of `quantum_px` rows and columns."""
    return tuple(int(-(-s // quantum_px) * quantum_px) for s in shape)


def max_window_px(tile_size_m: float, buffer_m: float, cell_m: float) -> int:
    """The largest side [cells] a buffered window of `split` can have (a core snapped
    outwards to the lattice, plus a buffer each side)."""
    return math.ceil(tile_size_m / cell_m - 1e-9) + 1 + 2 * math.ceil(buffer_m / cell_m - 1e-9)


def canonical_sides(tile_size_m: float, buffer_m: float, cell_m: float) -> tuple[int, ...]:
    """The square raster sides [cells] every window of this tiling is padded to: 128, 192,
    256, 384, 512, ... (2^k and 1.5 * 2^k) below the largest window, and the largest window
    rounded up to `SHAPE_QUANTUM_PX` (128, 192, 256, 384, 512, 640 for 500 m tiles, 50 m
    buffers and 1 m cells). Padding a window to the next side costs at most 2.25 times its
    cells (more for a thin strip), far less than compiling a raster program for each new
    window size (`experiments/results/canonical_shapes.md`)."""
    _check(tile_size_m, buffer_m, cell_m)
    largest = shape_bucket((max_window_px(tile_size_m, buffer_m, cell_m),) * 2)[0]
    sides, side = [], SMALLEST_SIDE_PX
    while side < largest:
        sides.append(side)
        if side * 3 // 2 < largest:
            sides.append(side * 3 // 2)
        side *= 2
    return (*sides, largest)


def canonical_capacities() -> tuple[int, ...]:
    """Point capacities `warmup` compiles: `CANONICAL_MIN_CAPACITY` times powers of 4 up to
    `CANONICAL_MAX_CAPACITY` (larger windows still run, at capacities compiled on demand)."""
    caps, cap = [], CANONICAL_MIN_CAPACITY
    while cap <= CANONICAL_MAX_CAPACITY:
        caps.append(cap)
        cap *= 4
    return tuple(caps)


def canonical_capacity(n: int) -> int:
    """Smallest `CANONICAL_MIN_CAPACITY * 4^k` holding `n` points, then powers of 2 beyond
    `CANONICAL_MAX_CAPACITY` (compiled on demand anyway: there the padding's memory counts
    more than a compile, a 5 M-point window padded to 8 M points, not 16 M)."""
    cap = CANONICAL_MIN_CAPACITY
    while cap < n:
        cap *= 4 if cap < CANONICAL_MAX_CAPACITY else 2
    return cap


def _canonical_shape(shape: tuple[int, int], sides: Sequence[int]) -> tuple[int, int]:
    need = max(shape)
    side = next((s for s in sides if s >= need), None)
    if side is None:
        raise ValueError(f"a window of {shape} cells is larger than the canonical sides {tuple(sides)}")
    return side, side


def _pad(tiles: Sequence[Tile], capacity: int, shape: tuple[int, int]) -> TileBatch:
    b = len(tiles)
    xyz = np.zeros((b, capacity, 3), np.float32)
    valid = np.zeros((b, capacity), bool)
    hw = np.zeros((b, 2), np.int32)
    for i, tile in enumerate(tiles):
        if tile.n_points > capacity or tile.shape[0] > shape[0] or tile.shape[1] > shape[1]:
            raise ValueError(f"tile {tile.key} ({tile.n_points} points, {tile.shape}) does not fit "
                             f"capacity {capacity} / shape {shape}")
        xyz[i, :tile.n_points] = tile.local_xyz
        valid[i, :tile.n_points] = True
        hw[i] = tile.shape
    return TileBatch(xyz=xyz, valid=valid, hw=hw, shape=tuple(shape), tiles=tuple(tiles))


def batches(tiles: Sequence[Tile], *, max_batch: int = 8, capacity: int | None = None,
            shape: tuple[int, int] | None = None, quantum_px: int = SHAPE_QUANTUM_PX,
            sides: Sequence[int] | None = None) -> Iterator[TileBatch]:
    """Group tiles by raster shape, and pad each group into batches of similar point counts.

    Args:
      tiles: from `split`.
      max_batch: most tiles per batch (bounds memory).
      capacity: force one point capacity (default: the bucket of the largest tile of a batch).
      shape: force one raster shape (default: each tile's shape bucket).
      quantum_px: shape bucket step in cells.
      sides: canonical square sides (`canonical_sides`): each tile is padded to the smallest
        that holds it, capacities are `canonical_capacity`, and a group runs in batches of
        exactly `max_batch` tiles, then one tile at a time, so only canonical shapes compile.
        None: shapes rounded to `quantum_px`, capacities `capacity_bucket`, batches of up to
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
            key = shape_bucket(tile.shape, quantum_px=quantum_px)
        groups.setdefault(key, []).append(tile)
    bucket = capacity_bucket if sides is None else canonical_capacity
    for group_shape, members in sorted(groups.items()):
        members = sorted(members, key=lambda t: t.n_points)
        if sides is None:
            chunks = [members[i:i + max_batch] for i in range(0, len(members), max_batch)]
        else:
            full = len(members) - len(members) % max_batch
            chunks = [members[i:i + max_batch] for i in range(0, full, max_batch)] + [[t] for t in members[full:]]
        for chunk in chunks:
            cap = capacity if capacity is not None else bucket(max(t.n_points for t in chunk))
            yield _pad(chunk, cap, group_shape)


def small_batches(tiles: Sequence[Tile], *, max_batch: int = 8) -> Iterator[TileBatch]:
    """Batches of windows of at most `SMALL_SIDES_PX[-1]` cells a side (a cloud of small groups
    far apart: `gfjax.io.tiled`), each padded to the smallest of `SMALL_SIDES_PX` holding it.

    A batch holds the cells of `max_batch` windows of the smallest canonical side, so more
    tiles when they are smaller (2,048 tiles of 8 x 8 cells for `max_batch` 8), and every batch
    is full: the last one is padded with copies of its last tile, whose outputs are not read
    (`TileBatch.tiles` holds the real ones), so each side compiles one program and a lone tile
    none of its own. Capacities are `capacity_bucket`s: a few points need no 16,384 slots.
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
            batch = _pad(chunk, capacity_bucket(max(t.n_points for t in chunk)), shape)
            extra = size - len(chunk)
            if extra:
                batch = batch._replace(**{name: np.concatenate([a, np.repeat(a[-1:], extra, axis=0)])
                                          for name, a in (("xyz", batch.xyz), ("valid", batch.valid), ("hw", batch.hw))})
            yield batch


def merge(n_points: int, tiles: Sequence[Tile], labels: Sequence[np.ndarray], *,
          fill: bool = False) -> np.ndarray:
    """Per-point labels of the whole cloud from per-tile labels, core points only.

    Args:
      n_points: size of the cloud.
      tiles: the tiles of `split`.
      labels: per tile, an array whose first `tile.n_points` entries label the tile's points
        (padded arrays are fine).
      fill: the value of points in no tile (not used).

    Returns:
      `(n_points,)` array of the labels' dtype.
    """
    if len(tiles) != len(labels):
        raise ValueError(f"got {len(labels)} label arrays for {len(tiles)} tiles")
    dtype = np.asarray(labels[0]).dtype if labels else np.bool_
    out = np.full(n_points, fill, dtype=dtype)
    for tile, lab in zip(tiles, labels):
        lab = np.asarray(lab)[:tile.n_points]
        out[tile.index[tile.core]] = lab[tile.core]
    return out


def tiled_estimator(*, max_batch: int, tile_bytes_per_cell: float, mosaic_bytes_per_cell: float):
    """The `memory_estimates(extent_m=None, tiling=None)` method of a `Config` whose method
    filters tile by tile (with a `cell_m`): a batch of up to `max_batch` tile rasters of
    `tile_bytes_per_cell` bytes a cell (the tiling's largest window: `tiling` a
    `Tiling`, default its defaults), and with `extent_m` (the cloud's x, y
    extent [m]) the whole-cloud mosaic of its diagnostics, `mosaic_bytes_per_cell` a cell."""

    def memory_estimates(self, extent_m: tuple[float, float] | None = None, tiling: Any = None) -> list[limits.Estimate]:
        tiling = Tiling() if tiling is None else tiling
        side = limits.raster_side(tiling.tile_size_m + 2 * tiling.buffer_m, self.cell_m)
        tiles = limits.tiles_per_batch(extent_m, tiling.tile_size_m, max_batch=max_batch)
        out = [limits.Estimate(f"a batch of {tiles} tile raster(s) of {side:,} x {side:,} cells "
                        "((tile_size_m + 2 buffer_m) / cell_m)", float(side) ** 2 * tiles * tile_bytes_per_cell,
                        ("cell_m", "tile_size_m", "buffer_m"))]
        if extent_m is not None:
            w, h = (limits.raster_side(e, self.cell_m) for e in extent_m)
            out.append(limits.Estimate(f"the whole-cloud rasters of {h:,} x {w:,} cells (extent / cell_m)",
                                float(h) * float(w) * mosaic_bytes_per_cell, ("cell_m",)))
        return out

    return memory_estimates
