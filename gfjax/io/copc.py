"""Cloud Optimized Point Cloud (COPC) files: the points in an x-y box, without reading the rest.

A COPC file is a LAZ 1.4 file whose chunks are the nodes of an octree, with a hierarchy that
gives each node's cube, byte range and point count (copc.io). So a box's points are read by
decompressing only the nodes whose cubes meet it (laspy's `CopcReader`), and each point keeps
its index in the file: the nodes lie in the file in the order of their byte offsets, so a
node's first point is the sum of the point counts of the nodes before it. Everything else
(the header, the checks, a full read) treats a COPC file as the LAZ file it is; a file written
from one is plain LAZ, every point and attribute kept, without COPC's layout records
(`without_layout`), unless its name ends in `.copc.laz`: then the octree is built again
(`gfjax.io.copc_writer`).
"""
from __future__ import annotations

import copy
import os
import struct
from operator import attrgetter
from pathlib import Path

import laspy
import numpy as np
from laspy.copc import Bounds, load_octree_for_query
from laspy.vlrs.vlrlist import VLRList

from gfjax.errors import InputError

SUFFIX = ".copc.laz"
_ENTRY = struct.Struct("<iiiiQii")      # a hierarchy entry: voxel key (d, x, y, z), offset, bytes, points


def check_hierarchy(source, root_offset: int, root_size: int, *, name: str) -> int:
    """Walk every page of a COPC hierarchy from the root page; returns the pages.

    laspy follows a page that names itself (or an earlier page) as a child for ever: here each
    page may be reached once, and must lie in the file.

    Raises:
      InputError: a page outside the file or reached twice (a loop), naming the file `name`.
    """
    size = source.seek(0, os.SEEK_END)
    todo, seen = [(int(root_offset), int(root_size))], set()
    while todo:
        offset, length = todo.pop()
        if offset in seen:
            raise InputError(f"{name}: its COPC hierarchy page at byte {offset:,} is reached twice (a loop)")
        if length < 0 or offset + length > size:
            raise InputError(f"{name}: its COPC hierarchy page at byte {offset:,} ({length:,} bytes) lies "
                             f"outside the file ({size:,} bytes)")
        seen.add(offset)
        source.seek(offset)
        page = source.read(length)
        for i in range(len(page) // _ENTRY.size):
            *_, child, child_bytes, points = _ENTRY.unpack_from(page, i * _ENTRY.size)
            if points == -1:
                todo.append((child, child_bytes))
    return len(seen)


def is_copc(path: str | os.PathLike, header: laspy.LasHeader | None = None) -> bool:
    """Whether a LAS/LAZ file (or its already read `header`) holds COPC's info record (user
    "copc", record 1), which the format puts first after the header."""
    if header is None:
        with laspy.open(path, read_evlrs=False) as reader:
            header = reader.header
    return any(v.user_id == "copc" and v.record_id == 1 for v in header.vlrs)


def without_layout(header: laspy.LasHeader, evlrs) -> tuple[laspy.LasHeader, VLRList | None]:
    """A copy of `header` and of the `evlrs` (a `VLRList` or None) without COPC's records (user "copc": the
    info, the hierarchy, copc-lib's extents). They describe how the octree's nodes lie in the
    file, which a rewritten file (plain LAZ, written in order) no longer has; laspy also
    refuses to write them. `header` and `evlrs` themselves when there are none."""
    if not any(v.user_id == "copc" for v in [*header.vlrs, *(evlrs or [])]):
        return header, evlrs
    header = copy.deepcopy(header)
    header.vlrs = VLRList(v for v in header.vlrs if v.user_id != "copc")
    return header, VLRList(v for v in evlrs or [] if v.user_id != "copc")


class Reader:
    """An open COPC file, queried box by box (a context manager).

    Attributes:
      path: the file.
      n_points: its points.
      read_points: points decompressed so far by `within` (the cost of the queries).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        source = open(self.path, "rb")
        try:
            self._reader = laspy.CopcReader(source)
            info = self._reader.copc_info
            check_hierarchy(source, info.hierarchy_root_offset, info.hierarchy_root_size, name=str(self.path))
            nodes = load_octree_for_query(self._reader.source, self._reader.copc_info, self._reader.root_page)
        except InputError:
            source.close()
            raise
        except Exception as err:  # noqa: BLE001 (laspy parsing the user's bytes: a bad file, not a bug)
            source.close()
            raise InputError(f"{self.path}: not a readable COPC file ({type(err).__name__}: {err})") from None
        self._first, start = {}, 0
        for node in sorted(nodes, key=attrgetter("offset")):
            self._first[node.key] = start
            start += node.point_count
        self.n_points = start
        self.read_points = 0
        if start != self._reader.header.point_count:
            source.close()
            raise InputError(f"{self.path}: its COPC hierarchy holds {start:,} points, its header "
                             f"{self._reader.header.point_count:,}")

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._reader.source.close()

    def within(self, lo: np.ndarray, hi: np.ndarray, scale_xy: float = 1.0) -> tuple[np.ndarray, laspy.ScaleAwarePointRecord]:
        """The points with `lo <= (x, y) * scale_xy <= hi`, from the nodes that meet the box.

        Args:
          lo, hi: float64 `(2,)`, the box's corners [m].
          scale_xy: metres per unit of the file's x and y.

        Returns:
          `(index, points)`: int64 `(k,)` the points' indices in the file, ascending, and their
          records `(k,)`.
        """
        lo_u, hi_u = np.asarray(lo, np.float64) / scale_xy, np.asarray(hi, np.float64) / scale_xy
        box = Bounds(np.array([*lo_u, -np.inf]), np.array([*hi_u, np.inf]))
        try:
            nodes = load_octree_for_query(self._reader.source, self._reader.copc_info, self._reader.root_page,
                                          query_bounds=box)
            nodes = sorted((n for n in nodes if n.point_count > 0), key=attrgetter("offset"))
            points = self._reader._fetch_and_decompress_points_of_nodes(nodes)
        except Exception as err:  # noqa: BLE001 (laspy/lazrs decoding the user's bytes: a bad file, not a bug)
            raise InputError(f"{self.path}: truncated or corrupt COPC data ({type(err).__name__}: {err})") from None
        self.read_points += len(points)
        index = np.concatenate([np.arange(self._first[n.key], self._first[n.key] + n.point_count) for n in nodes]
                               or [np.empty(0, np.int64)])
        x, y = np.asarray(points.x) * scale_xy, np.asarray(points.y) * scale_xy
        keep = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        return index[keep], points[keep]
