"""Cloud Optimized Point Cloud (COPC) files: the points in an x-y box, without reading the rest.

A COPC file is a LAZ 1.4 file whose chunks are the nodes of an octree, with a hierarchy that
gives each node's cube, byte range and point count (copc.io). So a box's points are read by
decompressing only the nodes whose cubes meet it (with laspy's `CopcReader`), and each point
keeps its index in the file: the nodes lie in the file in the order of their byte offsets, so a
node's first point is the sum of the point counts of the nodes before it. That is only true of
a hierarchy that tells the truth, so it is checked: its pages are walked once each (laspy
follows a loop, or a page without its node, for ever), its nodes must be the LAZ chunks one for
one (`check_chunks`), its cube finite, and each point in its node's square (`Reader.check_points`,
as the survey's index reads the file; `within` checks the points it reads). Everything else
(the header, the checks, a full read) treats a COPC file as the LAZ file it is; a file written
from one is plain LAZ, every point and attribute kept, without COPC's layout records
(`without_layout`), unless its name ends in `.copc.laz`: then the octree is built again
(`gfjax.io.copc_writer`).
"""
from __future__ import annotations

import copy
import io
import os
import struct
from operator import attrgetter
from pathlib import Path
from typing import NamedTuple

import laspy
import numpy as np
from laspy.vlrs.vlrlist import VLRList

from gfjax.errors import InputError

SUFFIX = ".copc.laz"
_ENTRY = struct.Struct("<iiiiQii")      # a hierarchy entry: voxel key (d, x, y, z), offset, bytes, points
_ROOT = (0, 0, 0, 0)


class Node(NamedTuple):
    """A node of a COPC octree: its voxel key `(level, x, y, z)` and its LAZ chunk."""

    key: tuple[int, int, int, int]
    offset: int           # the chunk's first byte
    byte_size: int        # its bytes
    point_count: int      # its points


def hierarchy(source, root_offset: int, root_size: int, *, name: str) -> list[Node]:
    """The nodes of a COPC octree reached from the root node through its hierarchy pages.

    A child-page entry (point count -1) of node `k` is followed once: the page must lie in the
    file, be reached once (laspy follows a page that names itself, or an earlier page, for
    ever) and hold node `k`'s own entry (laspy reads it again for ever when it does not); no
    node may be named twice. Entries that no path from the root reaches are ignored, as laspy
    ignores them.

    Raises:
      InputError: any of the above, or a node of fewer than 0 points, naming the file `name`.
    """
    size = source.seek(0, os.SEEK_END)
    entries: dict[tuple[int, int, int, int], tuple[int, int, int]] = {}
    seen: set[int] = set()

    def load(offset: int, length: int, pointed_by: tuple[int, int, int, int] | None) -> None:
        if offset in seen:
            raise InputError(f"{name}: its COPC hierarchy page at byte {offset:,} is reached twice (a loop)")
        if length < 0 or offset + length > size:
            raise InputError(f"{name}: its COPC hierarchy page at byte {offset:,} ({length:,} bytes) lies "
                             f"outside the file ({size:,} bytes)")
        seen.add(offset)
        source.seek(offset)
        page = source.read(length)
        for *key, child, child_bytes, points in _ENTRY.iter_unpack(page[:len(page) - len(page) % _ENTRY.size]):
            key = tuple(key)
            if key in entries and key != pointed_by:
                raise InputError(f"{name}: its COPC hierarchy names node {key} twice (the page at byte "
                                 f"{offset:,} again)")
            entries[key] = (child, child_bytes, points)
            pointed_by = None if key == pointed_by else pointed_by

    load(int(root_offset), int(root_size), None)
    nodes, todo = [], [_ROOT]
    while todo:
        key = todo.pop()
        if key not in entries:
            continue
        offset, length, points = entries[key]
        if points == -1:
            load(offset, length, key)
            if entries[key][2] == -1:
                raise InputError(f"{name}: its COPC hierarchy page at byte {offset:,} does not hold node {key}, "
                                 "whose entry points to it")
            offset, length, points = entries[key]
        if points < 0:
            raise InputError(f"{name}: node {key} of its COPC hierarchy holds {points:,} points")
        nodes.append(Node(key, offset, length, points))
        level, x, y, z = key
        todo.extend((level + 1, 2 * x + (i & 1), 2 * y + (i >> 1 & 1), 2 * z + (i >> 2)) for i in range(8))
    return nodes


def check_chunks(source, to_points: int, laszip: bytes, nodes: list[Node], *, name: str) -> None:
    """Whether the `nodes` that hold points are the LAZ chunks of the file, one for one: in
    byte order, the same offsets, byte sizes and point counts as its chunk table gives. A
    node's first point is then the sum of the points of the nodes before it, and its chunk
    decodes to exactly the points a full read finds there.

    Raises:
      InputError: a node that is not a chunk (or a chunk that is no node), naming the file `name`.
    """
    import lazrs

    source.seek(to_points)
    (table_at,) = struct.unpack("<q", source.read(8).ljust(8, b"\xff"))
    size = source.seek(0, os.SEEK_END)
    if not to_points + 8 <= table_at <= size - 8:
        raise InputError(f"{name}: truncated or corrupt LAZ data: chunk table offset {table_at:,} lies outside "
                         f"the file ({size:,} bytes)")
    source.seek(table_at)
    try:
        table = lazrs.read_chunk_table_only(io.BytesIO(source.read()), lazrs.LazVlr(laszip))
    except Exception as err:  # noqa: BLE001 (lazrs decoding the user's bytes)
        raise InputError(f"{name}: truncated or corrupt LAZ chunk table ({err})") from None
    chunks, at = [], to_points + 8
    for count, length in table:
        if count > 0:
            chunks.append((at, length, count))
        at += length
    held = sorted((n.offset, n.byte_size, n.point_count) for n in nodes if n.point_count > 0)
    for i, (node, chunk) in enumerate(zip(held + [None] * len(chunks), chunks + [None] * len(held))):
        if node != chunk:
            said = "" if node is None else f"a node of {node[2]:,} points in {node[1]:,} bytes at byte {node[0]:,}"
            found = "" if chunk is None else (f"chunk {i + 1} of {len(chunks)} ({chunk[2]:,} points in {chunk[1]:,} "
                                              f"bytes at byte {chunk[0]:,})")
            problem = (f"{said} where {found} lies" if node and chunk else f"{said} is no LAZ chunk" if node
                       else f"{found} is no node")
            raise InputError(f"{name}: its COPC hierarchy does not match its LAZ chunks: {problem}")


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

    Its hierarchy is checked as it opens (`hierarchy`, `check_chunks`, the octree's cube finite
    and not empty); `check_points` checks that points lie in their nodes' squares, which a
    box query trusts (a full read of the file passes each point through it: the survey's index).

    Attributes:
      path: the file.
      n_points: its points.
      read_points: points decompressed so far by `within` (the cost of the queries).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        name = str(self.path)
        source = open(self.path, "rb")
        try:
            self._reader = laspy.CopcReader(source)
            info, header = self._reader.copc_info, self._reader.header
            nodes = hierarchy(source, info.hierarchy_root_offset, info.hierarchy_root_size, name=name)
            check_chunks(source, header.offset_to_point_data, self._reader.laszip_vlr.record_data, nodes, name=name)
            center, half = np.asarray(info.center, np.float64), float(info.halfsize)
            if not (np.all(np.isfinite(center)) and np.isfinite(half) and half > 0):
                raise InputError(f"{name}: its COPC octree's cube (center {tuple(center.tolist())}, half size "
                                 f"{half}) is not a cube")
            scale_xy = np.abs(np.asarray(header.scales[:2], np.float64))
        except InputError:
            source.close()
            raise
        except Exception as err:  # noqa: BLE001 (laspy parsing the user's bytes: a bad file, not a bug)
            source.close()
            raise InputError(f"{name}: not a readable COPC file ({type(err).__name__}: {err})") from None
        # the nodes that hold points, in the file's order: a node's first point follows the last of those before it
        self._nodes = sorted((n for n in nodes if n.point_count > 0), key=attrgetter("offset"))
        counts = np.array([n.point_count for n in self._nodes], np.int64)
        self._end = np.cumsum(counts)
        self._first = self._end - counts
        self.n_points = int(counts.sum())
        self.read_points = 0
        if self.n_points != header.point_count:
            source.close()
            raise InputError(f"{name}: its COPC hierarchy holds {self.n_points:,} points, its header "
                             f"{header.point_count:,}")
        # each node's x-y square [file units], widened by a unit of the coordinates (a point on
        # an edge, rounded to the file's scale, may lie just outside)
        keys = np.array([n.key for n in self._nodes], np.int64).reshape(-1, 4)
        side = np.ldexp(2 * half, -keys[:, 0])[:, None]
        self._lo = center[:2] - half + keys[:, 1:3] * side - scale_xy
        self._hi = self._lo + side + 2 * scale_xy

    def __enter__(self) -> Reader:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._reader.source.close()

    def check_points(self, start: int, x: np.ndarray, y: np.ndarray) -> None:
        """Points `start`, `start + 1`, ... of the file, at `x`, `y` `(k,)` (the file's
        coordinates), each in the x-y square of its node: a box query reads the nodes whose
        squares meet the box, so a point outside its node's square could be missed.

        Raises:
          InputError: a point outside its node's square (a wrong voxel key or cube).
        """
        stop = start + len(x)
        first, last = np.searchsorted(self._end, start, side="right"), np.searchsorted(self._first, stop)
        node = np.repeat(np.arange(first, last), np.minimum(self._end[first:last], stop) -
                         np.maximum(self._first[first:last], start))
        if node.size != len(x):
            raise InputError(f"{self.path}: holds points past the {self.n_points:,} of its COPC hierarchy")
        self._check(start + np.arange(len(x)), node, x, y)

    def _check(self, index: np.ndarray, node: np.ndarray, x: np.ndarray, y: np.ndarray) -> None:
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        lo, hi = self._lo[node], self._hi[node]
        outside = np.flatnonzero(~((x >= lo[:, 0]) & (x <= hi[:, 0]) & (y >= lo[:, 1]) & (y <= hi[:, 1])))
        if outside.size:
            i = outside[0]
            raise InputError(f"{self.path}: point {index[i]:,} ({x[i]}, {y[i]}) lies outside the square of its "
                             f"COPC octree node {self._nodes[node[i]].key} (a wrong voxel key or cube)")

    def within(self, lo: np.ndarray, hi: np.ndarray, scale_xy: float = 1.0) -> tuple[np.ndarray, laspy.ScaleAwarePointRecord]:
        """The points with `lo <= (x, y) * scale_xy <= hi`, from the nodes whose squares meet the box.

        Args:
          lo, hi: float64 `(2,)`, the box's corners [m].
          scale_xy: metres per unit of the file's x and y.

        Returns:
          `(index, points)`: int64 `(k,)` the points' indices in the file, ascending, and their
          records `(k,)`.
        """
        lo_u, hi_u = np.asarray(lo, np.float64) / scale_xy, np.asarray(hi, np.float64) / scale_xy
        meet = np.flatnonzero(np.all((self._lo <= hi_u) & (self._hi >= lo_u), axis=1))
        nodes = [self._nodes[i] for i in meet]
        try:
            points = self._reader._fetch_and_decompress_points_of_nodes(nodes)
        except Exception as err:  # noqa: BLE001 (laspy/lazrs decoding the user's bytes: a bad file, not a bug)
            raise InputError(f"{self.path}: truncated or corrupt COPC data ({type(err).__name__}: {err})") from None
        self.read_points += len(points)
        counts = np.array([self._nodes[i].point_count for i in meet], np.int64)
        index = np.concatenate([np.arange(self._first[i], self._first[i] + n) for i, n in zip(meet, counts)]
                               or [np.empty(0, np.int64)])
        x, y = np.asarray(points.x), np.asarray(points.y)
        self._check(index, np.repeat(meet, counts), x, y)       # nodes in the file's order, as decompressed
        x, y = x * scale_xy, y * scale_xy
        keep = (x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1])
        return index[keep], points[keep]
