"""Writing a Cloud Optimized Point Cloud (COPC) file: the points as the nodes of an octree.

COPC (copc.io) is LAZ 1.4 in point format 6, 7 or 8 whose chunks are the nodes of an octree
over a cube around the points; a viewer or a box query reads the coarse nodes and only the fine
ones it needs. copc-lib compresses the nodes and writes the header, the COPC records and the
hierarchy; what is built here is which points go in which node:

- the points are visited in a fixed random order (so each node holds an even sample of its
  cube), and each goes to the shallowest node of its path that holds fewer than `node_points`
  points; the deepest level (`max_depth`) takes whatever is left, e.g. a stack of coincident
  points; within a node, points keep the order of the input;
- the root's spacing is the cube's side over `ROOT_CELLS` (as untwine and PDAL write it).

Nothing but the layout changes: every point and dimension, extra bytes (their descriptors as
read, min/max included), scales, offsets, the CRS (as WKT, which COPC requires) and the header's
identity fields are written as read. Formats 0-3 become 6 or 7 (LAS 1.4), the scan angle rank
kept as a scan angle, a format without GPS time gaining zeros. Every other VLR and EVLR of the
input follows copc-lib's records as an EVLR (COPC fixes which VLRs come before the points).
Waveform formats (4, 5, 9, 10) have no COPC form: `check_writable` refuses them.
"""
from __future__ import annotations

import os
import struct
import tempfile
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.vlrlist import VLRList

from gfjax.errors import InputError
from gfjax.io import columns, copc

NODE_POINTS = 100_000                   # points a node holds before the rest of its cube goes a level down
MAX_DEPTH = 20                          # 3 * 20 bits of cell code fit an int64
ROOT_CELLS = 128                        # the root's spacing: the cube's side over this
FORMATS = {0: 6, 1: 6, 2: 7, 3: 7, 6: 6, 7: 7, 8: 8}     # a point format -> the COPC format it is written as
SCAN_ANGLE_STEP_DEG = 0.006             # LAS 1.4 formats 6-10 store the scan angle in these steps
_EVLR_COUNT = struct.Struct("<I")       # LAS 1.4 public header block: the number of EVLRs, at byte 243
_EVLR_COUNT_AT = 243
_GUID_AT = 8                            # the project GUID's 16 bytes (copc-lib stops at a zero byte)
_KNOWN = {("laszip encoded", 22204), ("LASF_Spec", 4), ("LASF_Projection", 2112)}   # written by copc-lib
_GEOTIFF = {("LASF_Projection", 34735), ("LASF_Projection", 34736), ("LASF_Projection", 34737)}


def is_copc_name(path: str | os.PathLike) -> bool:
    """Whether an output named `path` is written as COPC (its name ends in `.copc.laz`)."""
    return str(path).lower().endswith(copc.SUFFIX)


def check_writable(header: laspy.LasHeader, target: str | os.PathLike, *, name: str) -> None:
    """Refuse, before any work, a COPC `target` for an input (`header`, file `name`) whose point
    format has no COPC form.

    Raises:
      InputError: waveform point formats (4, 5, 9, 10).
    """
    fmt = header.point_format.id
    if is_copc_name(target) and fmt not in FORMATS:
        raise InputError(f"{name}: point format {fmt} carries waveform packets, which COPC (point formats 6-8) "
                         f"cannot hold; write {target} as .laz instead")


def written_format(header: laspy.LasHeader) -> int:
    """The point format a COPC file of an input with `header` is written in."""
    return FORMATS[header.point_format.id]


def octree_nodes(xyz: np.ndarray, center: np.ndarray, halfsize: float, *, node_points: int = NODE_POINTS,
                 max_depth: int = MAX_DEPTH, seed: int = 0) -> list[tuple[tuple[int, int, int, int], np.ndarray]]:
    """The octree nodes of points, as COPC builders fill them (see the module docstring).

    Args:
      xyz: float64 `(n, 3)` point coordinates, inside the cube.
      center: float64 `(3,)` the cube's centre; halfsize: half its side (same units).
      node_points: points a node holds before the rest go a level deeper (>= 1).
      max_depth: the deepest level; its nodes hold every point left.
      seed: of the order points are visited in.

    Returns:
      `[(key, index)]`: each non-empty node's key `(depth, x, y, z)` (cell indices at that
      depth) and int64 `(k,)` its points, ascending; every point in exactly one node, keys in
      ascending order.
    """
    unit = (np.asarray(xyz, np.float64) - (np.asarray(center, np.float64) - halfsize)) / (2.0 * halfsize)
    left = np.random.default_rng(seed).permutation(len(unit))          # points not placed, in visiting order
    nodes = []
    for depth in range(max_depth + 1):
        if left.size == 0:
            break
        side = 1 << depth
        cells = np.clip((unit[left] * side).astype(np.int64), 0, side - 1)
        code = (cells[:, 0] * side + cells[:, 1]) * side + cells[:, 2]
        by_cell = np.argsort(code, kind="stable")                       # visiting order kept within a cell
        sorted_code = code[by_cell]
        first = np.flatnonzero(np.r_[True, sorted_code[1:] != sorted_code[:-1]])
        rank = np.arange(len(code)) - np.repeat(first, np.diff(np.r_[first, len(code)]))
        placed = np.zeros(len(code), bool)
        placed[by_cell[(rank < node_points) | (depth == max_depth)]] = True
        in_node, node_code = left[placed], code[placed]
        order = np.lexsort((in_node, node_code))
        in_node, node_code = in_node[order], node_code[order]
        starts = np.flatnonzero(np.r_[True, node_code[1:] != node_code[:-1]])
        for begin, end in zip(starts, np.r_[starts[1:], len(node_code)], strict=True):
            c = int(node_code[begin])
            nodes.append(((depth, c // (side * side), (c // side) % side, c % side), in_node[begin:end]))
        left = left[~placed]
    return nodes


def write(las: laspy.LasData, path: str | os.PathLike, *, name: str, wkt: str | None,
          node_points: int = NODE_POINTS, max_depth: int = MAX_DEPTH) -> np.ndarray:
    """Write `las` to `path` as a COPC file (see the module docstring).

    Args:
      las: the points and header to write (any point format of `FORMATS`).
      path: the file written (a temporary: the caller renames it into place).
      name: the output's name, for messages.
      wkt: the CRS as WKT when `las` has no WKT record of its own (a CRS read from GeoTIFF
        keys), or None.
      node_points, max_depth: the octree's (`octree_nodes`).

    Returns:
      int64 `(n,)`: the input index of each point in the file's order (the nodes' order).

    Raises:
      InputError: a point format without a COPC form; copc-lib could not write the file.
    """
    import copclib

    check_writable(las.header, path, name=name)
    wkt = _own_wkt(las) or wkt
    out = _as_copc_format(las)
    header = out.header
    n = len(out.points)
    xyz = np.column_stack([np.asarray(out.x), np.asarray(out.y), np.asarray(out.z)])
    lo, hi = (columns.lows(xyz), columns.highs(xyz)) if n else (np.zeros(3), np.zeros(3))
    center = (lo + hi) / 2
    halfsize = max(float((hi - lo).max()) / 2, float(np.max(header.scales))) * (1 + 1e-9)
    try:
        config = copclib.CopcConfigWriter(FORMATS[header.point_format.id], copclib.Vector3(*header.scales),
                                          copclib.Vector3(*header.offsets), wkt or "",
                                          _extra_bytes_record(header, las.header, Path(path).parent))
        info = config.copc_info
        info.center_x, info.center_y, info.center_z = map(float, center)
        info.halfsize = halfsize
        info.spacing = 2 * halfsize / ROOT_CELLS
        _copy_identity(header, config.las_header, lo, hi, np.asarray(out.return_number))
        writer = copclib.FileWriter(str(path), config)
        nodes = octree_nodes(xyz, center, halfsize, node_points=node_points, max_depth=max_depth)
        records = out.points.array
        for key, index in nodes:
            writer.AddNode(copclib.VoxelKey(*key), copclib.VectorChar(records[index].view(np.int8)))
        writer.Close()
    except RuntimeError as err:                      # copc-lib's errors (a full disk among them)
        raise InputError(f"{name}: cannot write COPC ({err})") from None
    _patch(Path(path), header.uuid.bytes_le, _other_records(las, has_wkt=bool(wkt)))
    return np.concatenate([index for _, index in nodes]) if nodes else np.empty(0, np.int64)


def _as_copc_format(las: laspy.LasData) -> laspy.LasData:
    """`las` in its COPC point format, LAS 1.4; `las` itself when it is in one already."""
    fmt = FORMATS[las.header.point_format.id]
    if las.header.point_format.id == fmt and las.header.version.minor >= 4:
        return las
    out = laspy.convert(las, point_format_id=fmt, file_version="1.4")
    if las.header.point_format.id < 6:                       # laspy leaves the new scan angle at 0
        out.scan_angle = np.round(np.asarray(las.scan_angle_rank, np.float64) / SCAN_ANGLE_STEP_DEG).astype(np.int16)
    return out


def _extra_bytes_record(header: laspy.LasHeader, read: laspy.LasHeader, folder: Path):
    """copc-lib's extra-bytes record for `header`'s extra dimensions, with the descriptors of
    `read` (the input's header, which a converted `header` no longer holds as read).

    copc-lib builds one from a file only: a one-point LAZ of this header is written (its
    descriptors' min/max put back as read, laspy having recomputed them) and read by copc-lib.
    """
    import copclib

    if not list(header.point_format.extra_dimension_names):
        return copclib.EbVlr(0)
    probe_header = laspy.LasHeader(point_format=header.point_format, version="1.4")
    probe_header.global_encoding.wkt = True              # copc-lib reads formats 6-8 with it only
    with tempfile.TemporaryDirectory(dir=folder, prefix=".gfjax-copc-") as tmp:
        probe = Path(tmp) / "extra-bytes.laz"
        with laspy.open(probe, "w", header=probe_header) as writer:
            writer.write_points(laspy.ScaleAwarePointRecord.zeros(1, header=probe_header))
            keep_extra_bytes_statistics(read, writer.header)
        return copclib.LazReader(str(probe)).laz_config.extra_bytes_vlr


def keep_extra_bytes_statistics(read: laspy.LasHeader, written: laspy.LasHeader) -> None:
    """Give the Extra Bytes descriptors of `written` the min/max fields of `read`, byte for byte.

    laspy recomputes them from the points it writes, so a file whose producer left them unset
    or stale would come back with other bytes than it had: a change of metadata the user did
    not ask for. The header is rewritten when the writer closes, so this runs before that.
    """
    before = {s.name: s for record in read.vlrs.get("ExtraBytesVlr") for s in record.extra_bytes_structs}
    for record in written.vlrs.get("ExtraBytesVlr"):
        for target in record.extra_bytes_structs:
            if target.name in before:
                target._min[:] = before[target.name]._min
                target._max[:] = before[target.name]._max


def _copy_identity(header: laspy.LasHeader, target, lo: np.ndarray, hi: np.ndarray, returns: np.ndarray) -> None:
    """The input header's identity fields onto copc-lib's header, and the points' bounds and
    counts by return (copc-lib counts the points only)."""
    import copclib

    target.min, target.max = copclib.Vector3(*map(float, lo)), copclib.Vector3(*map(float, hi))
    target.points_by_return = [int(c) for c in np.bincount(returns, minlength=16)[1:16]]
    target.file_source_id = int(header.file_source_id)
    target.global_encoding = int(header.global_encoding.value) | 0x10      # COPC: the CRS is WKT
    target.system_identifier = header.system_identifier
    target.generating_software = header.generating_software
    if header.creation_date is not None:
        target.creation_year = header.creation_date.year
        target.creation_day = header.creation_date.timetuple().tm_yday


def _own_wkt(las: laspy.LasData) -> str | None:
    """The WKT string of `las`'s own CRS record, as read; None when it has none."""
    for record in [*las.header.vlrs, *(las.evlrs or [])]:
        if isinstance(record, laspy.vlrs.known.WktCoordinateSystemVlr) and record.string.strip(" \t\r\n\0"):
            return record.string
    return None


def _other_records(las: laspy.LasData, *, has_wkt: bool) -> VLRList:
    """The input's VLRs and EVLRs that copc-lib does not write (GeoTIFF keys only when the CRS
    could not be given as WKT: formats 6-8 state it in WKT)."""
    skip = _KNOWN | (_GEOTIFF if has_wkt else set())
    return VLRList(r for r in [*las.header.vlrs, *(las.evlrs or [])]
                   if r.user_id != "copc" and (r.user_id, r.record_id) not in skip)


def _patch(path: Path, guid: bytes, records: VLRList) -> None:
    """Write the 16 bytes of the input's `guid` into the header, and append `records` as EVLRs
    after those copc-lib wrote (which end the file), counted in the header."""
    with open(path, "r+b") as f:
        f.seek(_GUID_AT)
        f.write(guid)
        if not records:
            return
        f.seek(_EVLR_COUNT_AT)
        (count,) = _EVLR_COUNT.unpack(f.read(_EVLR_COUNT.size))
        f.seek(0, os.SEEK_END)
        records.write_to(f, as_extended=True, encoding_errors="surrogateescape")
        f.seek(_EVLR_COUNT_AT)
        f.write(_EVLR_COUNT.pack(count + len(records)))
