"""Buffered square tiles of a cloud, and the merge of their core labels.

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
spread thin over a large box rasterises about its points, not its tiles. The tiles are
padded into batches for `jax.vmap` by `gfjax.tiling.batches`, to the sizes of
`gfjax.tiling.buckets`.

Host-side numpy (float64); a tile's `local_xyz` is float32 local metres.
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from gfjax import limits
from gfjax.errors import SettingError
from gfjax.io import columns
from gfjax.io.cloud import Frame
from gfjax.limits import Range
from gfjax.tiling.buckets import check_lattice

__all__ = ["Tiling", "Lattice", "RANGES", "WindowRows", "Tile", "split", "merge", "tiled_estimator"]

CROP_SAVING = 4.0             # a window shrinks to its core points' box + buffer when that is this many times smaller
FEW_CORES = 4                 # `split` finds the points of at most this many named tiles by masks


# The valid range of each tiling option (`Tiling`; `--tile-size`, `--buffer`).
RANGES: dict[str, Range] = {
    "tile_size_m": Range(0, 100_000, low_open=True, unit="m", extra=">= the method's cell"),
    "buffer_m": Range(0, 10_000, unit="m"),
}


class Lattice(NamedTuple):
    """A tiling at a method's raster cell: the three numbers `split` and
    `buckets.canonical_sides` take.

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


class WindowRows:
    """The float32 local coordinates `(m, 3)` [m] of a window's points, made from the cloud's
    float64 ones a slice of rows at a time, as `split` makes a tile's `local_xyz`: a survey's
    window of millions of points runs its programs a chunk at a time (`chunks`), so its 12 bytes
    a point are never held whole beside the cloud's own coordinates.

    Args:
      xyz_m: float64 `(n, 3)` the cloud's coordinates [m] (held, not copied).
      index: the window's rows in `xyz_m`, int `(m,)` or a `range`.
      origin_m: float64 `(3,)` the lattice's corner and the z origin [m].
      lo: int64 `(2,)` the window's south-west cell `(col, row)` on the lattice.
      cell_m: the lattice's cell [m]; cell_dtype: the integer type `split` computes cells in.
    """

    dtype = np.dtype(np.float32)
    ndim = 2

    def __init__(self, xyz_m: np.ndarray, index: np.ndarray | range, origin_m: np.ndarray, lo: np.ndarray,
                 cell_m: float, cell_dtype: Any):
        self.xyz_m, self.index, self.origin_m, self.lo = xyz_m, index, origin_m, lo
        self.cell_m, self.cell_dtype = cell_m, cell_dtype
        self.shape = (len(index), 3)

    def __len__(self) -> int:
        return self.shape[0]

    def rows(self, part: slice) -> np.ndarray:
        """Rows `part` (a slice with a step of 1) of the local coordinates: float32 `(k, 3)`."""
        take = self.index[part]
        if isinstance(take, range):              # consecutive rows: views of the cloud's columns
            take = slice(take.start, take.stop)
        shift = self.lo * self.cell_m
        out = np.empty((len(range(*part.indices(self.shape[0]))), 3), np.float32)
        out[:, 2] = self.xyz_m[take, 2] - self.origin_m[2]
        for j in range(2):
            values = self.xyz_m[take, j] - self.origin_m[j]
            cell = np.floor(np.divide(values, self.cell_m)).astype(self.cell_dtype) - self.lo[j]
            values -= shift[j]
            out[:, j] = values
            _clamp_into_cell(values, cell, self.cell_m, out=out[:, j])
        return out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.empty(self.shape, np.float32)
        for part in columns.slices(self.shape[0]):
            out[part] = self.rows(part)
        return out if dtype is None else out.astype(dtype, copy=False)


@dataclasses.dataclass(frozen=True, eq=False)
class Tile:
    """One buffered tile.

    Attributes:
      key: `(col, row)` of the tile core in the tiling (row 0 = southernmost).
      origin_m: float64 `(3,)`: the window's south-west corner (x, y) and the cloud's z
        origin [m]; local coordinates are `xyz_m - origin_m`.
      shape: raster `(h, w)` of the window at `cell_m` (its own extent, before padding).
      index: int64 `(m,)` indices into the cloud of the window's points; for the one tile of a
        frame naming one core (a survey's window) int32 under 2^31 points, or `range(m)` when
        the window is every point of the cloud in order (no 4 bytes a point held).
      core: bool `(m,)` which of them lie in the tile core.
      local_xyz: float32 `(m, 3)` local metres of those points, each clamped into the raster
        cell its float64 coordinates fall in; for the one tile of a frame naming one core, a
        `WindowRows` that makes them a slice of rows at a time (`np.asarray` gives them all).
      window_px: `(col, row)` of the window's south-west cell in the cloud's cell lattice
        (rows counted from the south).
      core_px: `(col0, row0, col1, row1)`: the core's cells `[col0, col1) x [row0, row1)` in
        the same lattice, clipped to the window (so to the cloud's extent).
    """

    key: tuple[int, int]
    origin_m: np.ndarray
    shape: tuple[int, int]
    index: np.ndarray | range
    core: np.ndarray
    local_xyz: np.ndarray | WindowRows
    window_px: tuple[int, int] = (0, 0)
    core_px: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def n_points(self) -> int:
        return len(self.index)


def _clamp_into_cell(values: np.ndarray, cell: np.ndarray, cell_m: float, out: np.ndarray) -> None:
    """Clamp `out`, float32 `(n,)` (a column: a strided view is fine), the values `values`
    (float64 `(n,)` [m]) rounded, so each stays inside the cell `cell` (int `(n,)`) its float64
    value is in; in place."""
    if not len(values):
        return
    # Only a value within a few float32 steps of its cell's edge can round out of it; the
    # others are left as they are (the clip would keep them), so the clip runs on few rows.
    largest = max(abs(float(values.min())), abs(float(values.max())))
    margin = 4.0 * float(np.spacing(np.float32(largest + cell_m)))
    offset = cell * cell_m
    np.subtract(values, offset, out=offset)
    near = np.flatnonzero((offset < margin) | (offset > cell_m - margin))
    del offset
    if near.size:
        c = cell[near]
        lo = (c * cell_m).astype(np.float32)
        hi = np.nextafter(((c + 1) * cell_m).astype(np.float32), np.float32(-np.inf))
        lo = np.where(np.floor(lo / np.float32(cell_m)) < c, np.nextafter(lo, np.float32(np.inf)), lo)
        out[near] = np.clip(out[near], lo, np.maximum(lo, hi))


def _core_box(cells: np.ndarray, of_core: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The lowest and highest cell `(col, row)`, int64 `(2,)` each, of the core points (`cells`
    int `(m, 2)` where `of_core`, bool `(m,)`, at least one)."""
    if of_core.all():
        return columns.lows(cells).astype(np.int64), columns.highs(cells).astype(np.int64)
    top = np.iinfo(cells.dtype)                # a column at a time, without copying the core's rows
    lows = np.array([cells[:, j].min(where=of_core, initial=top.max) for j in range(2)], np.int64)
    highs = np.array([cells[:, j].max(where=of_core, initial=top.min) for j in range(2)], np.int64)
    return lows, highs


def _cropped(lows: np.ndarray, highs: np.ndarray, reach_px: int, lo: np.ndarray,
             hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The window `[lo, hi)` (cells) cut to the box of its core points' cells (`lows`..`highs`,
    `_core_box`) grown by `reach_px`, when that box is at most `1 / CROP_SAVING` of it: a core
    of a few points in a mostly empty box rasterises their surroundings, not a whole tile."""
    box_lo = np.maximum(lows - reach_px, lo)
    box_hi = np.minimum(highs + 1 + reach_px, hi)
    if np.prod((box_hi - box_lo).astype(np.float64)) * CROP_SAVING > np.prod((hi - lo).astype(np.float64)):
        return lo, hi
    return box_lo, box_hi


def window_px(key: np.ndarray, extent_px: np.ndarray, tile_size_m: float, buffer_m: float,
              cell_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cells of tile `key` `(col, row)` on a lattice of `extent_px` `(2,)` cells (from the
    frame's corner): `(lo, hi, core_lo, core_hi)`, int64 `(2,)` each, the window `[lo, hi)`
    (its core grown by the buffer, before `_cropped`) and the core `[core_lo, core_hi)`, both
    clipped to the lattice. A point of cell `c` (`point_cells`) is in the window when
    `lo <= c < hi`."""
    key = np.asarray(key, np.int64)
    core_px = tile_size_m / cell_m
    buffer_px = math.ceil(buffer_m / cell_m - 1e-9)
    core_lo = np.floor(key * core_px).astype(np.int64)
    core_hi = np.minimum(np.ceil((key + 1) * core_px).astype(np.int64), extent_px)
    return np.maximum(core_lo - buffer_px, 0), np.minimum(core_hi + buffer_px, extent_px), core_lo, core_hi


def extent_cells(frame: Frame, cell_m: float) -> np.ndarray:
    """Cells `(cols, rows)` int64 `(2,)` of `frame`'s lattice of `cell_m` [m] that its points fill."""
    origin = np.asarray(frame.origin_m[:2], np.float64)
    return np.floor((np.asarray(frame.upper_m) - origin) / cell_m).astype(np.int64) + 1


def point_cells(xy_m: np.ndarray, frame: Frame, cell_m: float) -> np.ndarray:
    """Cell `(col, row)` int64 `(n, 2)` of points `xy_m` `(n, 2)` [m] on `frame`'s lattice of
    `cell_m`, computed as `split` computes it (the same float64 steps, so the same cells)."""
    origin = np.asarray(frame.origin_m[:2], np.float64)
    xy_m = np.asarray(xy_m, np.float64)
    cells = np.empty((len(xy_m), 2), np.int64)
    for j in range(2):                      # a column at a time: `xy_m` may be a view of wider rows
        scaled = (xy_m[:, j] - origin[j]) / cell_m
        cells[:, j] = np.floor(scaled, out=scaled)
    return cells


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
    check_lattice(tile_size_m, buffer_m, cell_m)
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    if xyz_m.ndim != 2 or xyz_m.shape[1] != 3:
        raise ValueError(f"xyz_m must have shape (n, 3), got {xyz_m.shape}")
    use = np.ones(len(xyz_m), bool) if use is None else np.asarray(use, dtype=bool)
    if use.shape != (len(xyz_m),):
        raise ValueError(f"use must have shape ({len(xyz_m)},), got {use.shape}")
    every_used = bool(use.all())
    for j in range(3):
        if not np.all(np.isfinite(xyz_m[:, j]), where=use):
            raise ValueError("xyz_m holds non-finite coordinates")
    if not use.any():
        return []
    lows = np.array([xyz_m[:, j].min(where=use, initial=np.inf) for j in range(3)])
    highs = np.array([xyz_m[:, j].max(where=use, initial=-np.inf) for j in range(2)])
    frame = Frame(lows, highs) if frame is None else frame
    origin = np.asarray(frame.origin_m, np.float64)
    if np.any(lows < origin) or np.any(highs > np.asarray(frame.upper_m)):
        raise ValueError("points lie outside the tiling frame")
    # Cells and tile keys from the coordinates less the origin (float64, >= 0); in int32 where
    # the lattice fits (the same values; a core spans at least one cell).
    extent_px = extent_cells(frame, cell_m)
    small = np.int32 if extent_px.max() < np.iinfo(np.int32).max else np.int64
    lattice = Lattice(tile_size_m, buffer_m, cell_m)
    if frame.cores is not None and len(frame.cores) == 1:
        tile = _one_tile(xyz_m, None if every_used else use, next(iter(frame.cores)), origin, extent_px, lattice, small)
        return [] if tile is None else [tile]
    used = np.flatnonzero(use)

    def column(j: int, rows: np.ndarray | None = None) -> np.ndarray:
        """Coordinate `j` of the used points, or of the points `rows` (indices into `xyz_m`):
        float64, a view when every point is used. A window holds millions of points: a column
        at a time, never an (n, 3) copy, and fresh pages cost more than the arithmetic on them."""
        if rows is not None:
            return xyz_m[rows, j]
        return xyz_m[:, j] if every_used else xyz_m[used, j]

    def less(j: int, offset: float, rows: np.ndarray | None = None) -> np.ndarray:
        """`column(j, rows) - offset`, in place when the column is a copy already."""
        values = column(j, rows)
        if np.may_share_memory(values, xyz_m):
            return np.subtract(values, offset)
        values -= offset
        return values

    cell, core = np.empty((used.size, 2), small), np.empty((used.size, 2), small)
    for j in range(2):
        cell[:, j], core[:, j] = _cells_and_cores(less(j, origin[j]), lattice, small)
    buffer_px = math.ceil(buffer_m / cell_m - 1e-9)

    reach = max(1, math.ceil((buffer_px + 1) * cell_m / tile_size_m))   # neighbour cores a window reaches
    if frame.cores is not None and len(frame.cores) <= FEW_CORES:
        # a survey's window made for one tile: a mask per tile, no sort of the window's points
        wanted = [k for k in sorted(frame.cores, key=lambda k: (k[1], k[0]))
                  if np.any((core[:, 0] == k[0]) & (core[:, 1] == k[1]))]

        def candidates_of(ti: int, tj: int) -> np.ndarray | None:
            near = (np.abs(core[:, 0] - ti) <= reach) & (np.abs(core[:, 1] - tj) <= reach)
            return None if near.all() else np.flatnonzero(near)
    else:
        by_core: dict[tuple[int, int], np.ndarray] = {}
        rows = int(core[:, 1].max()) + 1
        packed = core[:, 0].astype(np.int64) * rows + core[:, 1]   # by col, then row; one int64 sorts fast
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

        def candidates_of(ti: int, tj: int) -> np.ndarray | None:
            parts = [by_core[key] for dj in range(-reach, reach + 1) for di in range(-reach, reach + 1)
                     if (key := (ti + di, tj + dj)) in by_core]
            if len(parts) == 1:
                return parts[0]                              # sorted already
            found = np.concatenate(parts)
            found.sort()
            return found

    tiles = []
    for (ti, tj) in wanted:
        candidates = candidates_of(ti, tj)                # None: every point
        lo, hi, core_lo, core_hi = window_px(np.array([ti, tj]), extent_px, tile_size_m, buffer_m, cell_m)
        # A window of every point (a small file, a survey's window) gathers no copies: the
        # copies of millions of rows cost more than the arithmetic on them.
        every = candidates is None or len(candidates) == used.size     # candidates are sorted and distinct
        c = cell if every else cell[candidates]
        cc = core if every else core[candidates]
        of_core = (cc[:, 0] == ti) & (cc[:, 1] == tj)
        del cc
        if wanted[-1] == (ti, tj):
            del core                                     # its last use
        lo, hi = _cropped(*_core_box(c, of_core), buffer_px, lo, hi)
        inside = (c[:, 0] >= lo[0]) & (c[:, 0] < hi[0]) & (c[:, 1] >= lo[1]) & (c[:, 1] < hi[1])
        every = every and bool(inside.all())
        if candidates is None and not every:
            candidates = np.arange(used.size)
        members, in_core = (candidates, of_core) if every else (candidates[inside], of_core[inside])
        del inside, c
        shift = lo * cell_m
        if every and len(wanted) == 1:                   # the last use of `cell`
            local_cell = cell
            local_cell -= lo[None, :].astype(cell.dtype)
        else:
            local_cell = (cell if every else cell[members]) - lo[None, :]
        index = used if every else used[members]
        rows = None if every else index
        # local coordinates as (point - origin) - shift, each step rounded as before
        local32 = np.empty((index.size, 3), np.float32)
        local32[:, 2] = less(2, origin[2], rows)
        for j in range(2):                 # a column at a time: one float64 column alive, not two
            values = less(j, origin[j], rows)
            values -= shift[j]
            local32[:, j] = values
            _clamp_into_cell(values, local_cell[:, j], cell_m, out=local32[:, j])
            del values
        del local_cell
        shape = (int(hi[1] - lo[1]), int(hi[0] - lo[0]))
        core_lo, core_hi = np.maximum(core_lo, lo), np.minimum(core_hi, hi)
        tiles.append(Tile(key=(ti, tj), origin_m=origin + np.concatenate([shift, [0.0]]), shape=shape, index=index,
                          core=in_core, local_xyz=local32, window_px=(int(lo[0]), int(lo[1])),
                          core_px=(int(core_lo[0]), int(core_lo[1]), int(core_hi[0]), int(core_hi[1]))))
    return tiles


def _cells_and_cores(rel: np.ndarray, lattice: Lattice, dtype) -> tuple[np.ndarray, np.ndarray]:
    """The cells and tile cores along one axis, `dtype` `(n,)` each, of coordinates `rel`
    float64 `(n,)` [m] from the lattice's corner (consumed: it is scaled in place)."""
    cells = np.floor(np.divide(rel, lattice.cell_m)).astype(dtype)
    rel /= lattice.tile_size_m
    return cells, np.floor(rel, out=rel).astype(dtype)


def _one_tile(xyz_m: np.ndarray, use: np.ndarray | None, key: tuple[int, int], origin: np.ndarray,
              extent_px: np.ndarray, lattice: Lattice, small) -> Tile | None:
    """`split`'s tile `key` of a frame naming that one core (a survey's window), made
    a slice of points at a time (`columns.slices`): beside the tile, a few columns of a slice, not
    of the window's millions (`use`: the used points, None for all); its local coordinates are
    made again a chunk at a time where they are used (`WindowRows`). None when no used point
    lies in the core."""
    n = len(xyz_m)
    slices = columns.slices(n)

    def rows_of(part: slice) -> np.ndarray | slice:
        return part if use is None else np.flatnonzero(use[part]) + part.start

    def cells(rows: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray]:
        """Cells and cores `(k, 2)` of the points `rows`, as `split` makes them."""
        count = rows.stop - rows.start if isinstance(rows, slice) else len(rows)
        cell, core = np.empty((2, count, 2), small)
        for j in range(2):
            cell[:, j], core[:, j] = _cells_and_cores(xyz_m[rows, j] - origin[j], lattice, small)
        return cell, core

    # the core's points' box of cells, then the window's points (cells within it), slice by slice
    box_lo, box_hi = np.full(2, np.iinfo(np.int64).max), np.full(2, np.iinfo(np.int64).min)
    for part in slices:
        cell, core = cells(rows_of(part))
        of_core = (core[:, 0] == key[0]) & (core[:, 1] == key[1])
        if of_core.any():
            lows, highs = _core_box(cell, of_core)
            box_lo, box_hi = np.minimum(box_lo, lows), np.maximum(box_hi, highs)
    if box_lo[0] > box_hi[0]:
        return None
    buffer_px = math.ceil(lattice.buffer_m / lattice.cell_m - 1e-9)
    lo, hi, core_lo, core_hi = window_px(np.asarray(key), extent_px, *lattice)
    lo, hi = _cropped(box_lo, box_hi, buffer_px, lo, hi)
    count = n if use is None else int(np.count_nonzero(use))
    # rows of a cloud under 2^31 points in int32: a survey's window keeps them while it is
    # filtered; none when the window is every point in order (a survey's window of whole files)
    index = None
    in_core = np.empty(count, bool)
    start = 0
    for part in slices:
        rows = rows_of(part)
        cell, core = cells(rows)
        inside = (cell[:, 0] >= lo[0]) & (cell[:, 0] < hi[0]) & (cell[:, 1] >= lo[1]) & (cell[:, 1] < hi[1])
        if not inside.all():
            pick = np.flatnonzero(inside)
            rows = (np.arange(part.start, part.stop) if isinstance(rows, slice) else rows)[pick]
            core = core[pick]
        stop = start + len(core)
        if index is None and not (isinstance(rows, slice) and rows.start == start):
            index = np.empty(count, np.int32 if n <= np.iinfo(np.int32).max else np.int64)
            index[:start] = np.arange(start)
        if index is not None:
            index[start:stop] = np.arange(part.start, part.stop) if isinstance(rows, slice) else rows
        in_core[start:stop] = (core[:, 0] == key[0]) & (core[:, 1] == key[1])
        start = stop
    if index is None:
        index = range(count)
    elif start < count:                          # a cropped window: the rows its points filled
        index, in_core = index[:start].copy(), in_core[:start].copy()
    core_lo, core_hi = np.maximum(core_lo, lo), np.minimum(core_hi, hi)
    return Tile(key=tuple(int(k) for k in key), origin_m=origin + np.concatenate([lo * lattice.cell_m, [0.0]]),
                shape=(int(hi[1] - lo[1]), int(hi[0] - lo[0])), index=index, core=in_core,
                local_xyz=WindowRows(xyz_m, index, origin, lo, lattice.cell_m, small),
                window_px=(int(lo[0]), int(lo[1])),
                core_px=(int(core_lo[0]), int(core_lo[1]), int(core_hi[0]), int(core_hi[1])))


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
        lab = np.asarray(lab)
        for part in columns.slices(tile.n_points):            # a window's millions a slice at a time
            core = tile.core[part]
            rows = tile.index[part]
            if isinstance(rows, range):
                out[rows.start:rows.stop][core] = lab[part][core]
            else:
                out[rows[core]] = lab[part][core]
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
