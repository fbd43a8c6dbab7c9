"""A survey's catalog: each file's points filtered, kept on disk for its neighbours' halos.

One pass reads every file a chunk at a time (`gfjax.io.stream`, with the checks and unit
conversion of `gfjax.io.las.read`; memory is one chunk, not one file), refuses a survey whose files disagree on CRS or units (one line naming both files),
and stores the few per-point values a neighbour's halo needs (metres, class, returns,
whether it is ignored: 28 bytes a point) as a memory-mapped `.npy` in a private temporary folder;
on request (`keep_points`) also each file's point records as read (`gfjax.io.point_store`), from
which its classified copy is written without decompressing the file again. The
survey's `Frame` is the bounding box of every file's points filtered, exactly the frame one
file holding the whole survey would get.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import laspy
import numpy as np

from gfjax import limits
from gfjax.errors import InputError
from gfjax.io import asprs, columns, copc, point_store, stream
from gfjax.io import las as las_io
from gfjax.io.cloud import Frame, use_mask
from gfjax.limits import byte_size

BLOCK_POINTS = 1 << 20          # rows of a store read at a time
STORE = np.dtype([("xyz_m", "<f8", (3,)), ("classification", "u1"), ("return_number", "u1"),
                  ("number_of_returns", "u1"), ("ignored", "?")])


class Entry(NamedTuple):
    """One file of a survey.

    Attributes:
      path: the file.
      n_points: its points.
      frame: bounding box of its points filtered (`Frame`), or None when it has none.
      store: the `.npy` of its `STORE` records, or None for a COPC file (its records are read
        from the file, a box's from the octree nodes that meet it: `gfjax.io.copc`).
      scale_m: metres per unit of x, y and z.
      classes: the classes its filter ignores (`asprs.ClassRules`; for a COPC file's records).
      points: the `gfjax.io.point_store` of its point records as the file holds them (every
        dimension), or None when the catalog keeps none.
    """

    path: Path
    n_points: int
    frame: Frame | None
    store: Path | None
    scale_m: tuple[float, float, float] = (1.0, 1.0, 1.0)
    classes: asprs.ClassRules = asprs.DEFAULT_RULES
    points: Path | None = None

    def records(self) -> np.ndarray:
        """The file's `STORE` records `(n_points,)`, memory-mapped (index it with the few rows
        wanted: every page read stays resident while the map lives); a COPC file's, read."""
        if self.store is None:
            parts = [block for _, block in self.blocks()]
            return np.concatenate(parts) if parts else np.empty(0, STORE)
        return np.load(self.store, mmap_mode="r")

    def blocks(self, size: int = BLOCK_POINTS) -> Iterator[tuple[int, np.ndarray]]:
        """`(start, records)` of `size` rows at a time: a store's mapped read-only a block at a
        time (`gfjax.io.point_store.mapped`), so a pass over a file larger than memory holds one
        block; a COPC file's decompressed."""
        if self.store is None:
            with laspy.open(self.path, laz_backend=las_io.LAZ_BACKENDS) as reader:
                start = 0
                for chunk in reader.chunk_iterator(size):
                    yield start, to_records(chunk, self.scale_m, self.classes)
                    start += len(chunk)
            return
        offset = self._offset()
        for start in range(0, self.n_points, size):
            yield start, self._mapped(start, size, offset)

    def block(self, start: int, size: int = BLOCK_POINTS) -> np.ndarray:
        """The stored `STORE` records of rows `start` to `start + size` (or the file's end),
        mapped read-only as `blocks` gives them (not for a COPC file, which has no store)."""
        return self._mapped(start, size, self._offset())

    def _offset(self) -> int:
        """The store's header length [bytes]; no page of records read."""
        return np.load(self.store, mmap_mode="r").offset

    def _mapped(self, start: int, size: int, offset: int) -> np.ndarray:
        count = min(size, self.n_points - start)
        return point_store.mapped(self.store, STORE, count, offset + start * STORE.itemsize)

    def within(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points inside the x-y box `lo`..`hi` [m]: `(index, records)`, int64 `(k,)` their
        indices in the file, ascending, and their `STORE` records `(k,)`.

        Every point, when the entry's frame (the box of the points its filter uses) lies inside
        the box, so the few points a filter ignores may come from outside, unused. A COPC file
        decompresses only the octree nodes that meet the box.
        """
        frame = self.frame
        inside = frame is not None and np.all(frame.origin_m[:2] >= lo) and np.all(frame.upper_m <= hi)
        if self.store is None and not inside:
            with copc.Reader(self.path) as reader:
                index, points = reader.within(lo, hi, self.scale_m[0])
            return index, to_records(points, self.scale_m, self.classes)
        found, chosen = [], []
        for start, block in self.blocks():          # copied: a block's mapping leaves with it
            if inside:
                found.append(np.arange(start, start + len(block)))
                chosen.append(np.array(block))
                continue
            hit = np.flatnonzero(in_box(block["xyz_m"], lo, hi))
            found.append(start + hit)
            chosen.append(block[hit])
        return _joined(found, np.dtype(np.int64)), _joined(chosen, STORE)


def in_box(xyz_m: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Points `(n, 3)` [m] (a view of records is fine) whose x, y lie in `lo`..`hi` `(2,)`
    [m], bounds included: bool `(n,)`, tested a column at a time (strided views of 28-byte
    records, not 2-wide rows)."""
    x, y = xyz_m[:, 0], xyz_m[:, 1]
    inside = x >= lo[0]
    inside &= x <= hi[0]
    inside &= y >= lo[1]
    inside &= y <= hi[1]
    return inside


def _joined(parts: list[np.ndarray], dtype: np.dtype) -> np.ndarray:
    """`parts` one after another (the part itself when there is one: no copy)."""
    if len(parts) == 1:
        return parts[0]
    return np.concatenate(parts) if parts else np.empty(0, dtype)


def to_records(points, scale_m, classes: asprs.ClassRules = asprs.DEFAULT_RULES) -> np.ndarray:
    """`STORE` records `(n,)` of a chunk of a file's points (a laspy point record), its
    coordinates times `scale_m` (metres per unit of x, y, z), ignored as `classes` says."""
    part = np.empty(len(points), STORE)
    xyz = part["xyz_m"]
    for j, (axis, scale) in enumerate(zip((points.x, points.y, points.z), scale_m)):
        np.multiply(np.asarray(axis, np.float64), np.float64(scale), out=xyz[:, j])    # no (n, 3) temporary
    part["classification"] = np.asarray(points.classification, np.uint8)
    part["return_number"] = np.asarray(points.return_number, np.uint8)
    part["number_of_returns"] = np.asarray(points.number_of_returns, np.uint8)
    part["ignored"] = classes.ignored(points)
    return part


class Catalog(NamedTuple):
    """Every file of a survey and the survey's frame (None when no point is filtered)."""

    entries: tuple[Entry, ...]
    frame: Frame | None


def _describe(cloud) -> str:
    name = cloud.crs.name if cloud.crs is not None else "no CRS"
    return f"{name}, {cloud.horizontal_unit_m:g} m per unit"


def _units(cloud) -> tuple[float, float]:
    return (cloud.horizontal_unit_m, cloud.vertical_unit_m)


class _Indexed(NamedTuple):
    """One file's index (`index_file`), with what the survey's checks compare."""

    entry: Entry
    crs: object                   # pyproj.CRS or None
    units: tuple[float, float]
    description: str


def index(paths: Sequence[str | os.PathLike], folder: str | os.PathLike, *, returns: str = "all",
          units: str | None = None, trust_data: bool = False, client=None,
          classes: asprs.ClassRules = asprs.DEFAULT_RULES, keep_points: bool = False) -> Catalog:
    """Read every file once into a catalog whose stores live in `folder`.

    Args:
      paths: the survey's LAS/LAZ files (at least one).
      folder: an existing private folder for the stores (the caller removes it).
      returns: "all" or "last": the points filtered.
      units: `--units` override, or None for each file's CRS.
      trust_data: index the points a file holds when its header's count disagrees
        (`gfjax.io.las.read`).
      client: a `dask.distributed.Client` whose workers index the files, each file a task
        (`folder` must be one they reach), or None: here, two files at a time.
      classes: the classes the filter ignores (`asprs.ClassRules`).
      keep_points: also keep each file's point records as read (`Entry.points`: 1 byte on disk
        per byte of the point format), so its copy is written without reading the file again.

    Raises:
      InputError: an unreadable file, files whose CRS or units differ, a file whose points lie
        outside its header's bounds (the index would misplace it), or a file that duplicates
        another (same points and bounds: its points would count twice in their halos).
    """
    # on a cluster, absolute paths: workers resolve a relative one in their own working folder
    paths = [Path(p) if client is None else Path(p).absolute() for p in paths]
    check_scratch_space(paths, folder, keep_points=keep_points)
    jobs = [(i, path, Path(folder) / f"{i}.npy", Path(folder) / f"{i}.points.npy" if keep_points else None)
            for i, path in enumerate(paths)]
    options = dict(returns=returns, units=units, trust_data=trust_data, classes=classes)
    if client is not None:
        entries = _checked(_gathered(client, jobs, options))
    else:           # two files at a time: one's records are written while the other decompresses
        with ThreadPoolExecutor(min(2, limits.processors()), thread_name_prefix="gfjax-index") as pool:
            futures = [pool.submit(index_file, *job, **options) for job in jobs]
            try:
                entries = _checked(future.result() for future in futures)
            finally:          # after a failure, the files not yet begun are not read
                for future in futures:
                    future.cancel()
    frame = None
    for entry in entries:
        if entry.frame is not None:
            frame = entry.frame if frame is None else frame.union(entry.frame)
    return Catalog(tuple(entries), frame)


def _checked(done: Iterator[_Indexed]) -> list[Entry]:
    """The entries of the files indexed, in order, once each is checked against those before it:
    the same CRS and units, not the same tile twice (`InputError` otherwise)."""
    entries, first = [], None
    for indexed in done:
        entry = indexed.entry
        if first is None:
            first = indexed
        elif indexed.units != first.units or (indexed.crs is None) != (first.crs is None) or (
                indexed.crs is not None and not indexed.crs.equals(first.crs)):
            raise InputError(f"{entry.path}: CRS or units differ from {first.entry.path} ({indexed.description} vs "
                             f"{first.description}), so they are not one survey; filter them independently "
                             "(gfjax filter --independent)")
        for other in entries:
            if other.n_points == entry.n_points and _same_frame(other.frame, entry.frame):
                raise InputError(f"{entry.path}: holds as many points in the same bounds as {other.path}: "
                                 "the same tile twice? Filter one of them, or the files independently")
        entries.append(entry)
    return entries


def check_scratch_space(paths: Sequence[Path], folder: str | os.PathLike, *, keep_points: bool) -> None:
    """The stores of `paths` (their headers' point counts: `STORE` records, and the point records
    themselves with `keep_points`) must fit in `folder`'s free space, or `InputError` before any
    file is read. A file whose header does not read is left to the index to name."""
    import shutil

    need = 0
    for path in paths:
        try:
            with laspy.open(path) as reader:
                header = reader.header
                need += header.point_count * (STORE.itemsize + (header.point_format.size if keep_points else 0))
        except Exception:                                    # noqa: BLE001 (index_file says what is wrong)
            continue
    free = shutil.disk_usage(folder).free
    if need > free:
        raise InputError(f"{folder}: a survey of these files keeps about {byte_size(need)} of working copies "
                         f"there, only {byte_size(free)} free; set TMPDIR to a folder with more room, or filter "
                         "the files independently (gfjax filter --independent)")


def _gathered(client, jobs: list, options: dict) -> Iterator[_Indexed]:
    """`index_file` of each job as a task on `client`'s cluster, the results in order; after a
    failure the tasks not yet run are cancelled."""
    from gfjax.survey import cluster

    futures = [client.submit(index_file, *job, pure=False, **options) for job in jobs]
    try:
        for (_, path, *_), future in zip(jobs, futures):
            yield cluster.result(future, f"{path}: index")
    finally:
        client.cancel(futures)


def index_file(i: int, path: Path, store: Path, points_store: Path | None = None, *, returns: str = "all",
               units: str | None = None, trust_data: bool = False,
               classes: asprs.ClassRules = asprs.DEFAULT_RULES) -> _Indexed:
    """File `path` read once, a chunk at a time: its `STORE` records written to `store` (none
    for a COPC file: its hierarchy is checked, and each point against its octree node, so that
    its windows are read from the octree as a full read finds them), its point records as read
    to `points_store` when given (`gfjax.io.point_store`), the box of its points filtered, its
    bounds checked."""
    with stream.open_points(path, units=units, trust_data=trust_data) as points:
        scale = (points.horizontal_unit_m, points.horizontal_unit_m, points.vertical_unit_m)
        with contextlib.ExitStack() as stack:
            octree = None
            if copc.is_copc(path, points.header):    # its hierarchy checked, each point against its node
                store, octree = None, stack.enter_context(copc.Reader(path))
            if store is not None:       # a chunk at a time: mapped pages would stay resident
                offset = np.lib.format.open_memmap(store, mode="w+", dtype=STORE, shape=(points.n_points,)).offset
                out = stack.enter_context(open(store, "r+b"))
                out.seek(offset)
            kept = None
            if points_store is not None:
                kept = stack.enter_context(point_store.Writer(points_store, points.header.point_format.dtype(),
                                                              points.n_points))
            low = np.full(3, np.inf)
            high = np.full(3, -np.inf)
            box_lo, box_hi = np.full(3, np.inf), np.full(2, -np.inf)
            for start, chunk in points.chunks():
                if octree is not None:
                    octree.check_points(start, np.asarray(chunk.x), np.asarray(chunk.y))
                part = to_records(chunk, scale, classes)
                xyz = part["xyz_m"]
                lows, highs = columns.lows(xyz), columns.highs(xyz)
                low = np.minimum(low, lows / scale)
                high = np.maximum(high, highs / scale)
                used = use_mask(part["ignored"], part["return_number"], part["number_of_returns"], returns)
                if not used.all() and used.any():         # (a copy of the rows used only when some are not)
                    lows, highs = columns.lows(xyz[used]), columns.highs(xyz[used])
                if used.any():
                    box_lo = np.minimum(box_lo, lows)
                    box_hi = np.maximum(box_hi, highs[:2])
                if store is not None:
                    part.tofile(out)
                if kept is not None:
                    kept.append(chunk.array)
        _check_bounds(points, low, high)
        frame = Frame(box_lo, box_hi) if np.all(np.isfinite(box_lo)) else None
        return _Indexed(Entry(path, points.n_points, frame, store, scale, classes, points_store), points.crs,
                        _units(points),
                        _describe(points))


def _same_frame(a: Frame | None, b: Frame | None) -> bool:
    if a is None or b is None:
        return a is b
    return bool(np.array_equal(a.origin_m, b.origin_m) and np.array_equal(a.upper_m, b.upper_m))


def _check_bounds(points: stream.Stream, low: np.ndarray, high: np.ndarray) -> None:
    """Every point (`low`, `high`: their minimum and maximum x, y, z in file units) within the
    header's bounds (half a scale step of slack)."""
    if points.n_points == 0:
        return
    header = points.header
    slack = 0.5 * np.abs(np.asarray(header.scales, np.float64))
    if np.any(low < np.asarray(header.mins) - slack) or np.any(high > np.asarray(header.maxs) + slack):
        raise InputError(f"{points.path}: header bounds {np.round(header.mins, 3).tolist()} - "
                         f"{np.round(header.maxs, 3).tolist()} do not hold its points "
                         f"({np.round(low, 3).tolist()} - {np.round(high, 3).tolist()}); rewrite the header "
                         "(e.g. `pdal translate`, `las2las`)")
