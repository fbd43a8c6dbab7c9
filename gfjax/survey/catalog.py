"""A survey's catalog: each file's points filtered, kept on disk for its neighbours' halos.

One pass reads every file a chunk at a time (`gfjax.io.stream`, with the checks and unit
conversion of `gfjax.io.las.read`; memory is one chunk, not one file), refuses a survey whose files disagree on CRS or units (one line naming both files),
and stores the few per-point values a neighbour's halo needs (metres, class, returns,
whether it is ignored: 28 bytes a point) as a memory-mapped `.npy` in a private temporary folder. The
survey's `Frame` is the bounding box of every file's points filtered, exactly the frame one
file holding the whole survey would get.
"""
from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError
from gfjax.io import asprs, stream
from gfjax.io.cloud import use_mask
from gfjax.io.tiles import Frame

BLOCK_POINTS = 1 << 20          # rows of a store read at a time
STORE = np.dtype([("xyz_m", "<f8", (3,)), ("classification", "u1"), ("return_number", "u1"),
                  ("number_of_returns", "u1"), ("ignored", "?")])


class Entry(NamedTuple):
    """One file of a survey.

    Attributes:
      path: the file.
      n_points: its points.
      frame: bounding box of its points filtered (`Frame`), or None when it has none.
      store: the `.npy` of its `STORE` records.
    """

    path: Path
    n_points: int
    frame: Frame | None
    store: Path

    def records(self) -> np.ndarray:
        """The file's `STORE` records `(n_points,)`, memory-mapped (index it with the few rows
        wanted: every page read stays resident while the map lives)."""
        return np.load(self.store, mmap_mode="r")

    def blocks(self, size: int = BLOCK_POINTS) -> Iterator[tuple[int, np.ndarray]]:
        """`(start, records)` of `size` rows at a time, read into memory (not mapped, so a pass
        over a file larger than memory holds one block)."""
        offset = np.load(self.store, mmap_mode="r").offset          # the header's length; no page read
        for start in range(0, self.n_points, size):
            count = min(size, self.n_points - start)
            yield start, np.fromfile(self.store, dtype=STORE, count=count, offset=offset + start * STORE.itemsize)


class Catalog(NamedTuple):
    """Every file of a survey and the survey's frame (None when no point is filtered)."""

    entries: tuple[Entry, ...]
    frame: Frame | None


def _describe(cloud) -> str:
    name = cloud.crs.name if cloud.crs is not None else "no CRS"
    return f"{name}, {cloud.horizontal_unit_m:g} m per unit"


def _units(cloud) -> tuple[float, float]:
    return (cloud.horizontal_unit_m, cloud.vertical_unit_m)


def index(paths: Sequence[str | os.PathLike], folder: str | os.PathLike, *, returns: str = "all",
          units: str | None = None, trust_data: bool = False) -> Catalog:
    """Read every file once into a catalog whose stores live in `folder`.

    Args:
      paths: the survey's LAS/LAZ files (at least one).
      folder: an existing private folder for the stores (the caller removes it).
      returns: "all" or "last": the points filtered.
      units: `--units` override, or None for each file's CRS.
      trust_data: index the points a file holds when its header's count disagrees
        (`gfjax.io.las.read`).

    Raises:
      InputError: an unreadable file, files whose CRS or units differ, a file whose points lie
        outside its header's bounds (the index would misplace it), or a file that duplicates
        another (same points and bounds: its points would count twice in their halos).
    """
    entries, first = [], None
    for i, path in enumerate(map(Path, paths)):
        with stream.open_points(path, units=units, trust_data=trust_data) as points:
            if first is None:
                first = points
            elif _units(points) != _units(first) or (points.crs is None) != (first.crs is None) or (
                    points.crs is not None and not points.crs.equals(first.crs)):
                raise InputError(f"{path}: CRS or units differ from {first.path} ({_describe(points)} vs "
                                 f"{_describe(first)}), so they are not one survey; filter them independently "
                                 "(gfjax filter --independent)")
            store = Path(folder) / f"{i}.npy"
            offset = np.lib.format.open_memmap(store, mode="w+", dtype=STORE, shape=(points.n_points,)).offset
            with open(store, "r+b") as out:     # a chunk at a time: mapped pages would stay resident
                scale = np.array([points.horizontal_unit_m, points.horizontal_unit_m, points.vertical_unit_m])
                low = np.full(3, np.inf)
                high = np.full(3, -np.inf)
                box_lo, box_hi = np.full(3, np.inf), np.full(2, -np.inf)
                for start, chunk in points.chunks():
                    xyz = np.stack([np.asarray(chunk.x, np.float64), np.asarray(chunk.y, np.float64),
                                    np.asarray(chunk.z, np.float64)], axis=1)
                    low, high = np.minimum(low, xyz.min(axis=0)), np.maximum(high, xyz.max(axis=0))
                    xyz *= scale
                    part = np.empty(len(chunk), STORE)
                    part["xyz_m"] = xyz
                    part["classification"] = np.asarray(chunk.classification, np.uint8)
                    part["return_number"] = np.asarray(chunk.return_number, np.uint8)
                    part["number_of_returns"] = np.asarray(chunk.number_of_returns, np.uint8)
                    part["ignored"] = ignored = asprs.ignored_mask(chunk)
                    used = use_mask(ignored, part["return_number"], part["number_of_returns"], returns)
                    if used.any():
                        box_lo = np.minimum(box_lo, xyz[used].min(axis=0))
                        box_hi = np.maximum(box_hi, xyz[used, :2].max(axis=0))
                    out.seek(offset + start * STORE.itemsize)
                    out.write(part.tobytes())
            _check_bounds(points, low, high)
        frame = Frame(box_lo, box_hi) if np.all(np.isfinite(box_lo)) else None
        for other in entries:
            if other.n_points == points.n_points and _same_frame(other.frame, frame):
                raise InputError(f"{path}: holds as many points in the same bounds as {other.path}: "
                                 "the same tile twice? Filter one of them, or the files independently")
        entries.append(Entry(path, points.n_points, frame, store))
    frames = [e.frame for e in entries if e.frame is not None]
    frame = None
    for f in frames:
        frame = f if frame is None else frame.union(f)
    return Catalog(tuple(entries), frame)


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
