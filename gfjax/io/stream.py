"""LAS/LAZ files a chunk of points at a time: reading and rewriting files larger than memory.

`open_points` reads a file checked as `gfjax.io.las.read` checks it (its layout and point
count before any point, the int32 limits of every chunk, a truncated file at the end; its CRS
and unit factors) in chunks of `CHUNK_POINTS`; `rewrite` copies a file into a new one with
only the classification changed, chunk by chunk, atomically (`gfjax.io.atomic`), keeping the
header, every VLR/EVLR and every point dimension. Memory is one chunk, whatever the file's size
(but for a COPC output, whose octree is built over every point: `gfjax.io.copc_writer`).
"""
from __future__ import annotations

import contextlib
import copy
import os
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import laspy
import numpy as np

from gfjax.errors import InputError
from gfjax.io import asprs, copc_writer, point_store
from gfjax.io import las as las_io
from gfjax.io.atomic import atomic_output
from gfjax.io.cloud import use_mask

CHUNK_POINTS = 1 << 20          # points a chunk holds (about 30-70 MB of point records)


class Stream:
    """An open LAS/LAZ file, read a chunk at a time (`open_points`).

    Attributes:
      path: the file.
      header: its header (`point_count` the points it holds).
      n_points: points it holds.
      horizontal_unit_m, vertical_unit_m: its unit factors, and crs its CRS or None
        (`gfjax.io.las.header_crs_units`).
    """

    def __init__(self, path: Path, reader: laspy.LasReader, n_points: int, found: las_io.CRSUnits,
                 stored: Path | None = None):
        self.path, self._reader, self.n_points, self._stored = path, reader, n_points, stored
        self.header = reader.header
        self.crs = found.crs
        self.horizontal_unit_m, self.vertical_unit_m = found.units.horizontal_m, found.units.vertical_m

    def chunks(self, size: int | None = None) -> Iterator[tuple[int, laspy.ScaleAwarePointRecord]]:
        """`(start, points)` for each chunk, in file order: `points` are the file's points
        `start` to `start + len(points)`.

        Raises:
          InputError: truncated or corrupt data, or stored coordinates at the int32 limits.
        """
        if self._stored is not None:            # checked when the store was written
            header = self.header
            for start, records in point_store.blocks(self._stored, size or CHUNK_POINTS):
                yield start, laspy.ScaleAwarePointRecord(records, header.point_format, header.scales, header.offsets)
            return
        kind = "LAZ" if self.header.are_points_compressed else "LAS"
        start = 0
        try:
            for points in self._reader.chunk_iterator(size or CHUNK_POINTS):
                if len(points) == 0:
                    break
                las_io.check_int32_limits(self.path, points)
                yield start, points
                start += len(points)
        except (InputError, MemoryError):         # ours, and a machine too small: not a bad file
            raise
        except Exception as err:  # noqa: BLE001 (laspy/lazrs decoding the user's bytes: a bad file, not a bug)
            detail = f"decompression failed: {err}" if kind == "LAZ" else str(err)
            raise InputError(f"{self.path}: truncated or corrupt {kind} data ({detail})") from None
        if start != self.n_points:
            raise InputError(f"{self.path}: truncated {kind} file: header says {self.n_points} points, "
                             f"the file holds {start}")


@contextlib.contextmanager
def open_points(path: str | os.PathLike, *, units: str | None = None, trust_data: bool = False,
                stored: str | os.PathLike | None = None) -> Iterator[Stream]:
    """A `Stream` over a LAS 1.0-1.4 or LAZ file's points; with `stored`, their chunks come from
    that `gfjax.io.point_store` of them (a survey's, written from this stream's chunks), not
    from the file.

    Raises:
      InputError: as `gfjax.io.las.read`.
    """
    path = Path(path)
    header, layout = las_io._read_header(path, trust_data=trust_data)
    found = las_io.header_crs_units(header, name=str(path), units=units)
    try:
        reader = laspy.open(path, laz_backend=las_io.LAZ_BACKENDS)
    except Exception as err:  # noqa: BLE001 (laspy parsing the user's bytes: a bad file, not a bug)
        raise InputError(f"{path}: not a valid LAS/LAZ header ({type(err).__name__}: {err})") from None
    with reader:
        reader.header.point_count = layout.data_count
        yield Stream(path, reader, layout.data_count, found, None if stored is None else Path(stored))


def rewrite(source: str | os.PathLike, target: str | os.PathLike,
            classify: Callable[[int, laspy.ScaleAwarePointRecord], np.ndarray], *, force: bool = False,
            input_paths: Iterable[str | os.PathLike] = (), trust_data: bool = False,
            staged: Path | None = None, exclusive: bool = False, stored: str | os.PathLike | None = None) -> Path:
    """Copy `source` to `target` atomically with each chunk's classification replaced.

    Args:
      source: a LAS/LAZ file.
      target: the output (LAZ when its suffix is `.laz`).
      classify: `classify(start, points) -> (len(points),) uint8`: the new classes of the
        points `start` to `start + len(points)` of `source`.
      force, input_paths, exclusive: as `gfjax.io.las.write`.
      staged: a temporary name beside `target` (`gfjax.io.atomic.temporary_name`): the copy is
        written there and left for the process that named it to commit (`gfjax.io.atomic.commit`).
      trust_data: as `gfjax.io.las.read`.
      stored: `source`'s points as a survey's catalog kept them (`open_points`), or None.

    Returns:
      The path written.
    """
    source, target = Path(source), Path(target)
    as_copc = copc_writer.is_copc_name(target)
    compress = target.suffix.lower() == ".laz" and not as_copc
    # units only scale what a filter reads; a copy needs none (and a file in degrees is fine)
    with open_points(source, trust_data=trust_data, units="m", stored=stored) as stream:
        if as_copc:
            with atomic_output(target, force=force, input_paths=[*input_paths, source],
                               suffixes=las_io.LAS_SUFFIXES, staged=staged, exclusive=exclusive) as tmp:
                copc_writer.write(_relabelled(stream, classify), tmp, name=str(target),
                                  wkt=None if stream.crs is None else stream.crs.to_wkt())
            return target
        backends = las_io._compressors(stream.header.point_format.id, target) if compress else None
        with atomic_output(target, force=force, input_paths=[*input_paths, source],
                           suffixes=las_io.LAS_SUFFIXES, staged=staged, exclusive=exclusive) as tmp, open(tmp, "w+b") as raw:
            f = las_io._KeepWriteError(raw)
            try:
                # the writer counts and bounds what it writes in its header: not the reader's
                header, evlrs = las_io.writable(copy.deepcopy(stream.header), stream._reader.evlrs)
                with laspy.LasWriter(f, header, do_compress=compress, laz_backend=backends, closefd=False,
                                     encoding_errors="surrogateescape") as writer:
                    for start, points in stream.chunks():
                        points.classification = classify(start, points)
                        writer.write_points(points)
                    if header.version.minor >= 4 and evlrs:
                        writer.write_evlrs(evlrs)
            except UnicodeError as err:
                raise InputError(f"{target}: cannot write the text fields of {source} unchanged: LAS text "
                                 f"is ASCII ({err})") from None
            except InputError:
                raise
            except Exception:
                if f.error is not None:
                    raise f.error from None
                raise
    return target


def _relabelled(stream: Stream, classify: Callable[[int, laspy.ScaleAwarePointRecord], np.ndarray]) -> laspy.LasData:
    """Every point of `stream` in memory with the classes `classify` gives (as `rewrite`): a
    COPC file's octree is built over all of its points."""
    parts = []
    for start, points in stream.chunks():
        points.classification = classify(start, points)
        parts.append(points.array)
    header = copy.deepcopy(stream.header)
    las = laspy.LasData(header, laspy.ScaleAwarePointRecord(
        np.concatenate(parts) if parts else np.zeros(0, header.point_format.dtype()), header.point_format,
        header.scales, header.offsets))
    las.evlrs = stream._reader.evlrs
    return las


def relabel(source: str | os.PathLike, target: str | os.PathLike, ground: np.ndarray, *, returns: str = "all",
            reset_nonground: bool = False, force: bool = False, input_paths: Iterable[str | os.PathLike] = (),
            trust_data: bool = False, staged: Path | None = None,
            classes: asprs.ClassRules = asprs.DEFAULT_RULES, exclusive: bool = False,
            stored: str | os.PathLike | None = None) -> tuple[int, int]:
    """Copy `source` to `target` (`rewrite`) with the classes that `ground` says, bool
    `(n_points,)` (array-like; read a chunk at a time, so a memory map stays unread), as
    `Cloud.with_ground` sets them: ground 2; former ground 1 (every non-ground point 1 with
    `reset_nonground`); the points the filter does not use (`returns`, the classes `classes`
    ignores: noise, withheld) and those of the classes it keeps keep their class. `stored`: as
    `rewrite`.

    Returns:
      `(n_ground, n_points)` written.
    """
    counts = [0, 0]

    def classify(start: int, points) -> np.ndarray:
        n = len(points)
        used = use_mask(classes.ignored(points), np.asarray(points.return_number),
                        np.asarray(points.number_of_returns), returns)
        classification = np.asarray(points.classification)
        mine = np.asarray(ground[start:start + n], bool) & used & ~classes.kept(classification)
        counts[0] += int(mine.sum())
        counts[1] += n
        return asprs.relabel(classification, mine, used, reset_nonground=reset_nonground, rules=classes)

    rewrite(source, target, classify, force=force, input_paths=input_paths, trust_data=trust_data, staged=staged,
            exclusive=exclusive, stored=stored)
    return counts[0], counts[1]
