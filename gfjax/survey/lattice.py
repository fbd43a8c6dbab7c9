"""A survey filtered tile by tile: each tile of a lattice on the survey's frame filtered once.

A tiled method's labels for a tile's core depend only on the points of the tile's window, so
a survey is filtered tile by tile rather than file by file: a tile's window is gathered from
whichever files overlap it (their catalog stores), filtered on the survey's frame restricted
to that one tile (`Frame.only`), and its core points' labels are kept in their file's label
store (1 byte a point in the catalog's folder, mapped only while a tile writes it or a caller
reads it, so this process holds no label of the survey's files). A file's labels are ready once
the tiles holding its points are done. Each tile runs once, however many files it meets (a
500 m tile over 200 m files meets about nine), and memory follows the largest window, not the
survey or the files.

A method that does not tile runs out of core the same way on `Pieces`: squares of the frame,
each filtered with the points within a halo around it (as a survey's file is,
`gfjax.survey.halo`), its own points' labels kept; labels near a piece's edge are then close
to, not exactly, those of one file (as near a file's edge in a survey).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np

from gfjax import heap, limits
from gfjax.result import Result
from gfjax.survey import cluster
from gfjax.survey.catalog import STORE, Catalog, Entry, in_box
from gfjax.survey.halo import Points, ground_near, overlaps, tiles_region
from gfjax.tiling import tiles
from gfjax.tiling.tiles import Lattice, Tiling

MIN_PIECE_M = 50.0          # the smallest side `pieces` gives a piece [m]


class Pieces(NamedTuple):
    """The squares a method that does not tile is run on out of core (`TileLabels`): sides of
    `tile_size_m` [m] laid from the survey frame's corner, each filtered with the points within
    `halo_m` [m] around it (the method's survey halo, `gfjax.survey.halo.halo_width`)."""

    tile_size_m: float
    halo_m: float


def pieces(catalog: Catalog, halo_m: float, tile_size_m: float = Tiling().tile_size_m) -> Pieces:
    """`Pieces` whose windows (a piece and its halo) are one tile of `tile_size_m` [m] (the
    method's own tiling, whose rasters then run as one tile, not as four mostly of buffer),
    smaller where the densest file's points in a window would not fit the memory budget
    (`limits`); at least `MIN_PIECE_M`."""
    def density(frame, n_points: int) -> float:
        """Points a square metre of a file's box (at least 1 m²)."""
        span = np.asarray(frame.upper_m, np.float64) - np.asarray(frame.origin_m[:2], np.float64)
        return n_points / max(float(np.prod(span)), 1.0)

    densest = max((density(e.frame, e.n_points) for e in catalog.entries if e.frame is not None), default=0.0)
    window = tile_size_m
    if densest > 0:
        window = min(window, math.sqrt(limits.memory_budget_bytes() / (densest * limits.IN_MEMORY_BYTES_PER_POINT)))
    return Pieces(max(MIN_PIECE_M, window - 2 * halo_m), halo_m)


class TileLabels:
    """The labels of a survey's points under a tiled method, or a method run on `Pieces`,
    computed tile by tile on demand.

    Args:
      catalog: the survey (`gfjax.survey.index`; its frame is not None).
      filter_fn: `filter_fn(points, returns, core) -> Result` on a `Points` window, `core` bool
        `(n,)` the points whose labels are kept.
      lattice: the method's tiling at its cell (`gfjax.methods.lattice`), or the `Pieces` of a
        method that does not tile.
      folder: the catalog's private folder (the label stores go there).
      returns: "all" or "last".
    """

    def __init__(self, catalog: Catalog, filter_fn: Callable, lattice: Lattice | Pieces, folder: str | Path, *,
                 returns: str = "all"):
        self.catalog, self.filter_fn, self.lattice, self.returns = catalog, filter_fn, lattice, returns
        self.stores, self.keys, self.done, self.pending = [], [], set(), {}
        for i, entry in enumerate(catalog.entries):
            self.stores.append(Path(folder) / f"{i}.ground.npy")
            np.lib.format.open_memmap(self.stores[-1], mode="w+", dtype=np.bool_, shape=(entry.n_points,))
            # the tiles its box of points filtered meets (from the index: no point read); one
            # without a point of the file labels none of them, one without any point filtered
            # in its core runs no filter
            frame = entry.frame
            self.keys.append(set() if frame is None else self._keys_over(frame.origin_m[:2], frame.upper_m))

    def _keys_over(self, lo: np.ndarray, hi: np.ndarray) -> set[tuple[int, int]]:
        """The keys `(col, row)` of the tiles whose cores meet the x-y box `lo`..`hi` [m]."""
        first, last = self.key_of(np.stack([lo, hi]))
        return {(c, r) for c in range(int(first[0]), int(last[0]) + 1) for r in range(int(first[1]), int(last[1]) + 1)}

    def key_of(self, xy_m: np.ndarray) -> np.ndarray:
        """`tile_key` on this survey."""
        return tile_key(xy_m, self.catalog, self.lattice)

    def _box(self, i: int, margin_m: float) -> tuple[np.ndarray, np.ndarray] | None:
        """File `i`'s bounding box grown by `margin_m` [m], `(lo (2,), hi (2,))`, or None."""
        frame = self.catalog.entries[i].frame
        if frame is None or margin_m <= 0:
            return None
        return (np.asarray(frame.origin_m[:2], np.float64) - margin_m,
                np.asarray(frame.upper_m, np.float64) + margin_m)

    def labels(self, i: int, margin_m: float = 0.0) -> np.ndarray:
        """File `i`'s labels, bool `(n_i,)` memory-mapped, once every tile holding its points
        (and, with `margin_m`, every tile within that of its bounding box) has run."""
        needed = set(self.keys[i])
        box = self._box(i, margin_m)
        if box is not None:
            needed |= self._keys_over(*box) & set().union(*self.keys)
        for key in sorted(needed - self.done, key=lambda k: (k[1], k[0])):
            self._run(key)
        return self._labels_of(i)

    def _labels_of(self, i: int, *, writable: bool = False) -> np.ndarray:
        """File `i`'s label store, bool `(n_i,)`, mapped while the caller holds it: a survey's
        labels stay on disk, not in this process's memory (1 byte a point of every file)."""
        return np.load(self.stores[i], mmap_mode="r+" if writable else "r")

    def near_ground(self, i: int, margin_m: float) -> np.ndarray:
        """The other files' ground points within `margin_m` of file `i`'s bounding box, float64
        `(k, 3)` [m] (after `labels(i, margin_m)`)."""
        box = self._box(i, margin_m)
        if box is None:
            return np.empty((0, 3), np.float64)
        return ground_near(self.catalog, i, *box, self._labels_of)

    def _run(self, key: tuple[int, int]) -> None:
        """Filter tile `key` (here, or on the cluster that `submit` sent it to) and store its
        core points' labels."""
        future = self.pending.pop(key, None)

        def here():
            return tile_labels(self.catalog, self.filter_fn, self.lattice, key, returns=self.returns)

        parts = here() if future is None else cluster.result(future, f"survey tile {key}", again=here)
        for j, index, ground in parts:
            store = self._labels_of(j, writable=True)
            store[index] = ground            # the page cache keeps it: no sync to disk
            del store
        self.done.add(key)

    def submit(self, submit: Callable) -> None:
        """Send every tile not yet done to a cluster: `submit(tile_labels, lattice, key,
        returns=...)` returns a future of `tile_labels(catalog, filter_fn, lattice, key, ...)`
        (`gfjax.survey.run`'s submitter, over `dask.distributed.Client.submit`); `labels`
        then waits for the tiles it needs instead of running them here. Files come first in
        catalog order, so the first file's tiles finish first."""
        for i in range(len(self.catalog.entries)):
            for key in sorted(self.keys[i] - self.done - self.pending.keys(), key=lambda k: (k[1], k[0])):
                self.pending[key] = submit(tile_labels, self.lattice, key, returns=self.returns)


def tile_key(xy_m: np.ndarray, catalog: Catalog, lattice: Lattice | Pieces) -> np.ndarray:
    """Tile key `(col, row)` int64 `(n, 2)` of points `xy_m` `(n, 2)` [m] on the survey's
    lattice, as `gfjax.tiling.tiles.split` computes it."""
    origin = np.asarray(catalog.frame.origin_m[:2], np.float64)
    return np.floor((np.asarray(xy_m, np.float64) - origin) / lattice.tile_size_m).astype(np.int64)


def in_tile(xyz_m: np.ndarray, catalog: Catalog, lattice: Lattice | Pieces, key: tuple[int, int]) -> np.ndarray:
    """Points `(n, 3)` [m] in the core of tile `key`: bool `(n,)`, `tile_key(...) == key` a
    column at a time."""
    origin = np.asarray(catalog.frame.origin_m[:2], np.float64)
    inside = np.ones(len(xyz_m), bool)
    for j in range(2):
        inside &= np.floor((xyz_m[:, j] - origin[j]) / lattice.tile_size_m) == key[j]
    return inside


class _Part(NamedTuple):
    """The rows of a survey window that one file gives from one block of its store.

    Attributes:
      j: the file.
      rows: the rows in file `j`, ascending: a `range`, or uint32 (int64 past 2^32 points) `(k,)`.
      start: the first row of the store's block that `rows` (an array) lie in (`Entry.block`):
        the window reads them there again when it is joined, so its points are copied once.
      held: the rows' `STORE` records themselves, where no store holds them (a COPC file's
        read), else None.
    """

    j: int
    rows: range | np.ndarray
    start: int = 0
    held: np.ndarray | None = None


def tile_labels(catalog: Catalog, filter_fn: Callable, lattice: Lattice | Pieces, key: tuple[int, int], *,
                returns: str = "all") -> list[tuple[int, np.ndarray, np.ndarray]]:
    """Tile `key` filtered from its window's points, gathered from every file it meets (a
    piece's window: the piece grown by its halo, filtered on the survey's whole frame).

    A pure function of the catalog (its stores are read, nothing is written), so it runs in
    any process that reaches the catalog's folder: a Dask worker's too.

    Returns:
      `(j, index, ground)` per file `j` with points in the tile's core: `index` uint32 or
      int64 `(k,)` of those points in file `j`, `ground` bool `(k,)` their labels.
    """
    if isinstance(lattice, Pieces):
        return _piece_labels(catalog, filter_fn, lattice, key, returns=returns)
    frame = catalog.frame
    window_lo, window_hi, _, _ = tiles.window_px(np.asarray(key), tiles.extent_cells(frame, lattice.cell_m), *lattice)
    lo, hi = tiles_region(np.asarray(key), np.asarray(key), frame, lattice)       # a cell wider than the window
    # a file whose points filtered lie a cell within the window's edges lies in it whole
    origin = np.asarray(frame.origin_m[:2], np.float64)
    sure_lo, sure_hi = origin + (window_lo + 1) * lattice.cell_m, origin + (window_hi - 1) * lattice.cell_m

    def pick(entry: Entry, records: np.ndarray) -> np.ndarray | None:
        """Exactly the window's points (`split`'s cells): `split` then cuts the tile without copying them."""
        box = entry.frame
        if np.all(box.origin_m[:2] >= sure_lo) and np.all(box.upper_m <= sure_hi):
            return None
        return _in_window(records, frame, lattice, window_lo, window_hi)

    parts = _window_parts(catalog, lo, hi, pick)
    return _core_labels(catalog, filter_fn, lattice, key, parts, frame.only([key]), returns=returns)


def _window_parts(catalog: Catalog, lo: np.ndarray, hi: np.ndarray,
                  pick: Callable[[Entry, np.ndarray], np.ndarray | None]) -> list[_Part]:
    """The `_Part`s of a window inside the x-y box `lo`..`hi` [m], file by file and block by
    block: `pick(entry, records)` gives the offsets, int64 ascending, of the window's rows among
    a block's `STORE` records, or None for every row (then none is read). Only the rows are kept,
    not the points: a block's mapping leaves with it."""
    parts = []
    for j, entry in enumerate(catalog.entries):
        if not overlaps(entry.frame, lo, hi):
            continue
        if entry.store is None:              # a COPC file: the octree nodes that meet the box, read
            index, records = entry.within(lo, hi)
            mine = pick(entry, records)
            if mine is not None:
                index, records = index[mine], records[mine]
            if index.size:
                parts.append(_Part(j, _rows(index), held=records))
            continue
        for start, block in entry.blocks():
            mine = pick(entry, block)
            rows = range(start, start + len(block)) if mine is None else _rows(start + mine)
            del block
            if len(rows):
                parts.append(_Part(j, rows, start))
    return parts


def _in_window(records: np.ndarray, frame, lattice: Lattice, window_lo: np.ndarray,
               window_hi: np.ndarray) -> np.ndarray:
    """The rows, int64 `(k,)` ascending, of the `STORE` records whose cells (`tiles.point_cells`
    on `frame`'s lattice) lie in the window `[window_lo, window_hi)`."""
    cells = tiles.point_cells(records["xyz_m"][:, :2], frame, lattice.cell_m)
    inside = (cells[:, 0] >= window_lo[0]) & (cells[:, 0] < window_hi[0])
    inside &= (cells[:, 1] >= window_lo[1]) & (cells[:, 1] < window_hi[1])
    return np.flatnonzero(inside)


def _piece_labels(catalog: Catalog, filter_fn: Callable, pieces: Pieces, key: tuple[int, int], *,
                  returns: str = "all") -> list[tuple[int, np.ndarray, np.ndarray]]:
    """`tile_labels` of a piece: its points and those within its halo, from every file they lie in."""
    origin = np.asarray(catalog.frame.origin_m[:2], np.float64)
    lo = origin + np.asarray(key, np.float64) * pieces.tile_size_m - pieces.halo_m
    hi = lo + pieces.tile_size_m + 2 * pieces.halo_m

    def pick(entry: Entry, records: np.ndarray) -> np.ndarray | None:
        """`Entry.within`'s rows: every row of a file whose frame lies inside the box."""
        if np.all(entry.frame.origin_m[:2] >= lo) and np.all(entry.frame.upper_m <= hi):
            return None
        return np.flatnonzero(in_box(records["xyz_m"], lo, hi))

    parts = _window_parts(catalog, lo, hi, pick)
    return _core_labels(catalog, filter_fn, pieces, key, parts, catalog.frame, returns=returns)


def _core_labels(catalog: Catalog, filter_fn: Callable, lattice: Lattice | Pieces, key: tuple[int, int],
                 parts: list[_Part], frame, *, returns: str) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The window of `parts` (`_window_parts`) filtered on `frame`, and the labels of tile
    `key`'s core points, per file (`tile_labels`' value)."""
    if not parts:
        return []
    points = _joined(catalog, parts, f"survey tile {key}", frame)
    # the gather's block-sized temporaries freed holes that glibc keeps between the window's
    # arrays; the window's larger arrays fit none of them, so give them back now (`heap.trim`)
    heap.trim()
    in_core = in_tile(points.xyz_m, catalog, lattice, key)
    if not np.any(in_core & points.filter_mask(returns)):       # a tile of the files' boxes, not of their points
        return []
    result: Result = filter_fn(points, returns=returns, core=in_core)
    ground = np.asarray(result.ground, bool)
    del points, result
    out, start = [], 0
    for part in parts:
        take = part.rows
        stop = start + len(take)
        mine = in_core[start:stop]
        index = np.flatnonzero(mine) + take.start if isinstance(take, range) else take[mine]
        if index.size:
            small = catalog.entries[part.j].n_points <= np.iinfo(np.uint32).max
            out.append((part.j, index.astype(np.uint32) if small else index, ground[start:stop][mine]))
        start = stop
    return out


def _rows(take: np.ndarray) -> np.ndarray | range:
    """A file's rows in a window, `take` int64 `(k,)` ascending: a `range` when they are
    consecutive (a file wholly inside: no 8 bytes a point held while the window is filtered),
    else `take` in uint32 where they fit (4 bytes a point)."""
    if take.size and int(take[-1]) - int(take[0]) + 1 == take.size:
        return range(int(take[0]), int(take[-1]) + 1)
    return take.astype(np.uint32) if take.size and int(take[-1]) <= np.iinfo(np.uint32).max else take


def _joined(catalog: Catalog, parts: list[_Part], name: str, frame) -> Points:
    """The `Points` of `parts` one after another, each field copied once from its store's
    block (mapped again: a window's points are never held twice), or from the records a part
    holds (dropped from `parts` once copied)."""
    n = sum(len(part.rows) for part in parts)
    fields = {field: np.empty((n, *STORE[field].shape), STORE[field].base) for field in STORE.names}
    at = 0
    for k, part in enumerate(parts):
        rows = part.rows
        if part.held is not None:
            records, take = part.held, None
            parts[k] = part._replace(held=None)
        elif isinstance(rows, range):
            records, take = catalog.entries[part.j].block(rows.start, len(rows)), None
        else:
            records, take = catalog.entries[part.j].block(part.start), rows - rows.dtype.type(part.start)
        stop = at + len(rows)
        for field, out in fields.items():
            if take is None:
                out[at:stop] = records[field]
            else:
                np.take(records[field], take, axis=0, out=out[at:stop])
        at = stop
        del records, take
    return Points(**fields, name=name, frame=frame)
