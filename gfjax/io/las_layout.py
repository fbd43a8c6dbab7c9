"""The byte layout of a LAS/LAZ file, checked against the file size before laspy reads it.

laspy trusts the header: a count of 4 billion VLRs is looped over, a count of 10**15 points is
allocated, and a header that under-counts its points silently drops the rest. `check_layout`
reads the public header block with `struct` (ASPRS LAS 1.0-1.4, "Public Header Block") and
checks every count, length and offset against the bytes the file holds, so that each check is
bounded by the file size and nothing is allocated from a header value alone.

For uncompressed points the number of points present is exact: the bytes between the offset to
point data and the next structure (first EVLR, internal wave packets, or the end of the file),
divided by the record length. For LAZ it comes from the chunk table: exact for the layered
point formats 6-10 (each chunk states its point count and layer sizes, which are checked
against the chunk) and for variable-size chunks; for fixed-size chunks of formats 0-5 (the
usual LASzip layout: every chunk but the last holds `chunk_size` points) the last chunk is decompressed with the header's count and compressed
again, which reproduces its bytes exactly when the count is right; when it does not, the count
that does reproduce them (if any) is the number of points present. An encoder that does not
reproduce lazrs/LASzip output gives no evidence, and the header is then believed.
"""
from __future__ import annotations

import dataclasses
import io
import math
import os
import stat
import struct
from pathlib import Path

from gfjax.errors import InputError

SIGNATURE = b"LASF"
# Point formats per version that laspy reads (a file gfjax reads, it must be able to write back).
VERSION_FORMATS = {(1, 0): (0, 1), (1, 1): (0, 1), (1, 2): (0, 1, 2, 3), (1, 3): (0, 1, 2, 3, 4, 5),
                   (1, 4): (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10)}
SUPPORTED_VERSIONS = tuple(VERSION_FORMATS)
# Versions laspy reads but does not write, and the version they are written as: LAS 1.2 holds
# every field of a LAS 1.0 header and point (its global encoding replaces a reserved 0).
WRITTEN_AS = {(1, 0): (1, 2)}
# The largest coordinate a scale and offset may reach: beyond any survey in any linear unit down to
# millimetres, and float64 still resolves 0.1 mm there, so the arithmetic of every method stays finite.
MAX_COORDINATE = 1e12
# Size of the public header block per minor version (bytes).
_HEADER_SIZE = {0: 227, 1: 227, 2: 227, 3: 235, 4: 375}
# Minimum point record length per point format (bytes); more is extra bytes.
POINT_SIZE = {0: 20, 1: 28, 2: 26, 3: 34, 4: 57, 5: 63, 6: 30, 7: 36, 8: 38, 9: 59, 10: 67}
_VLR_HEADER = 54
_EVLR_HEADER = 60
_LASZIP_USER_ID = b"laszip encoded"
_LASZIP_RECORD_ID = 22204
_VARIABLE_CHUNKS = 0xFFFFFFFF
# Most points one byte of LAZ data can hold: constant points compress to about 150 per byte
# with LASzip's coders (50,000-point chunks, formats 0-10); the bound leaves a wide margin.
MAX_LAZ_POINTS_PER_BYTE = 1000
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
# Largest fixed LAZ chunk accepted beyond the file's own point count (LASzip writes 50,000).
MAX_IDLE_CHUNK_POINTS = 1_000_000


@dataclasses.dataclass(frozen=True)
class Layout:
    """What the header claims and what the file holds.

    Attributes:
      version: `(major, minor)`.
      point_format: the point format id (compression bits cleared).
      record_length: bytes per point record.
      compressed: LAZ points.
      header_count: points the header claims.
      data_count: points the file holds; equal to `header_count` unless they disagree.
    """

    version: tuple[int, int]
    point_format: int
    record_length: int
    compressed: bool
    header_count: int
    data_count: int


def check_regular_file(path: str | os.PathLike) -> os.stat_result:
    """`os.stat` of `path`, refusing anything but a regular file before it is opened.

    Raises:
      InputError: missing, a folder, a FIFO, a device or a socket, or a name the system refuses
        (too long, a loop of links, no permission to look).
    """
    name = os.fspath(path)
    if name == "":
        raise InputError("'': empty file name")
    try:
        info = os.stat(name)
    except FileNotFoundError:
        raise InputError(f"{name}: no such file") from None
    except OSError as err:
        raise InputError(f"{name}: cannot open ({err.strerror or err})") from None
    mode = info.st_mode
    if stat.S_ISREG(mode):
        return info
    if stat.S_ISDIR(mode):
        raise InputError(f"{name}: is a folder, not a LAS/LAZ file")
    kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else
            "a character device" if stat.S_ISCHR(mode) else
            "a block device" if stat.S_ISBLK(mode) else
            "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise InputError(f"{name}: is {kind}, not a LAS/LAZ file")


def check_layout(path: str | os.PathLike) -> Layout:
    """Check the header of a LAS/LAZ file against its size; the file must be a regular file.

    Raises:
      InputError: naming the file and the header field: not LAS, a truncated header, an
        unsupported version or point format, a record length, header size, offset, VLR or EVLR
        count or length that does not fit the file, a zero/NaN/inf scale, a NaN/inf offset or
        extent, a corrupt LAZ chunk table. A point count that disagrees with the data is not
        raised here: it is returned (`Layout.data_count`).
    """
    path = Path(path)
    size = check_regular_file(path).st_size
    try:
        with open(path, "rb") as f:
            return _check(f, size, str(path))
    except OSError as err:
        raise InputError(f"{path}: cannot read ({err.strerror or err})") from None


def _fail(name: str, problem: str) -> InputError:
    return InputError(f"{name}: {problem}")


def _check(f, size: int, name: str) -> Layout:
    head = f.read(_HEADER_SIZE[4])
    if head[:4] != SIGNATURE:
        raise _fail(name, f"not a LAS/LAZ file (signature {head[:4]!r}, expected {SIGNATURE!r})")
    if len(head) < _HEADER_SIZE[0]:
        raise _fail(name, f"not a valid LAS/LAZ header (truncated: the file has {size} bytes, a LAS "
                          f"header at least {_HEADER_SIZE[0]})")
    major, minor = head[24], head[25]
    if (major, minor) not in SUPPORTED_VERSIONS:
        raise _fail(name, f"LAS version {major}.{minor} is not supported (1.0 to 1.4)")
    need = _HEADER_SIZE[minor]
    if len(head) < need:
        raise _fail(name, f"not a valid LAS/LAZ header (truncated: the file has {size} bytes, a LAS "
                          f"{major}.{minor} header {need})")
    header_size, offset, n_vlrs, format_byte, record_length, legacy_count = struct.unpack_from("<HIIBHI", head, 94)
    scales = struct.unpack_from("<3d", head, 131)
    offsets = struct.unpack_from("<3d", head, 155)
    extents = struct.unpack_from("<6d", head, 179)
    count = legacy_count
    start_evlr = n_evlrs = 0
    if minor >= 4:
        start_evlr, n_evlrs, count = struct.unpack_from("<QIQ", head, 235)

    compressed = bool(format_byte & 0x80)
    point_format = format_byte & 0x3F
    if point_format not in POINT_SIZE:
        raise _fail(name, f"point data format {point_format} is not supported (0 to 10)")
    if point_format not in VERSION_FORMATS[major, minor]:
        allowed = VERSION_FORMATS[major, minor]
        raise _fail(name, f"point data format {point_format} is not part of LAS {major}.{minor} "
                          f"(formats {allowed[0]} to {allowed[-1]})")
    if record_length < POINT_SIZE[point_format]:
        raise _fail(name, f"point data record length {record_length} is less than the "
                          f"{POINT_SIZE[point_format]} bytes of point format {point_format}")
    if header_size < need:
        raise _fail(name, f"header size {header_size} is less than the {need} bytes of a LAS {major}.{minor} header")
    if offset > size:
        raise _fail(name, f"offset to point data {offset} lies past the end of the file ({size} bytes)")
    if header_size > offset:
        raise _fail(name, f"header size {header_size} is larger than the offset to point data {offset}")
    for axis, scale in zip("xyz", scales):
        if not math.isfinite(scale) or scale == 0.0:
            raise _fail(name, f"{axis} scale factor is {scale!r} (must be a finite number other than 0)")
    for axis, value in zip("xyz", offsets):
        if not math.isfinite(value):
            raise _fail(name, f"{axis} offset is {value!r} (must be finite)")
    for axis, scale, value in zip("xyz", scales, offsets):
        reach = abs(value) + abs(scale) * 2.0**31
        if reach > MAX_COORDINATE:
            raise _fail(name, f"{axis} scale factor {scale:g} with offset {value:g} lets coordinates exceed "
                              f"{MAX_COORDINATE:g} units (the most gfjax takes)")
    for field, value in zip(("max x", "min x", "max y", "min y", "max z", "min z"), extents):
        if not math.isfinite(value):
            raise _fail(name, f"{field} in the header is {value!r} (must be finite)")

    laszip = _walk_vlrs(f, name, header_size, offset, n_vlrs)
    if n_evlrs:
        _walk_evlrs(f, name, size, offset, start_evlr, n_evlrs)
    if compressed:
        if laszip is None:
            raise _fail(name, "compressed points (LAZ) but no LASzip VLR")
        data_count = _laz_count(f, name, size, offset, record_length, count, laszip)
    else:
        end = size
        if n_evlrs and start_evlr >= offset:
            end = min(end, start_evlr)
        if minor >= 3 and head[6] & 0b10:  # wave packets stored inside the file
            (start_waves,) = struct.unpack_from("<Q", head, 227)
            if offset <= start_waves < end:
                end = start_waves
        data_count = (end - offset) // record_length
    return Layout((major, minor), point_format, record_length, compressed, count, data_count)


def _walk_vlrs(f, name: str, header_size: int, offset: int, n_vlrs: int) -> bytes | None:
    """Check that `n_vlrs` VLRs fit between the header and the point data; the LASzip VLR."""
    room = offset - header_size
    if n_vlrs > room // _VLR_HEADER:
        raise _fail(name, f"number of VLRs {n_vlrs} cannot fit in the {room} bytes between the header "
                          f"and the point data (each takes at least {_VLR_HEADER})")
    f.seek(header_size)
    block = f.read(room)
    pos, laszip = 0, None
    for i in range(n_vlrs):
        if pos + _VLR_HEADER > room:
            raise _fail(name, f"VLR {i + 1} of {n_vlrs} starts past the offset to point data {offset}")
        user_id = block[pos + 2:pos + 18].rstrip(b"\0")
        record_id, length = struct.unpack_from("<HH", block, pos + 18)
        body = pos + _VLR_HEADER
        if body + length > room:
            raise _fail(name, f"VLR {i + 1} of {n_vlrs} (record length {length}) runs past the offset to "
                              f"point data {offset}")
        if user_id == _LASZIP_USER_ID and record_id == _LASZIP_RECORD_ID:
            laszip = block[body:body + length]
        pos = body + length
    return laszip


def _walk_evlrs(f, name: str, size: int, offset: int, start: int, n_evlrs: int) -> None:
    """Check that `n_evlrs` EVLRs fit between `start` and the end of the file."""
    if start < offset or start > size:
        raise _fail(name, f"start of first EVLR {start} lies outside the file's data "
                          f"({offset} to {size} bytes)")
    if n_evlrs > (size - start) // _EVLR_HEADER:
        raise _fail(name, f"number of EVLRs {n_evlrs} cannot fit in the {size - start} bytes after the "
                          f"start of the first EVLR (each takes at least {_EVLR_HEADER})")
    pos = start
    for i in range(n_evlrs):
        f.seek(pos + 20)
        raw = f.read(8)
        if len(raw) < 8:
            raise _fail(name, f"EVLR {i + 1} of {n_evlrs} starts past the end of the file")
        (length,) = struct.unpack("<Q", raw)
        pos += _EVLR_HEADER + length
        if pos > size:
            raise _fail(name, f"EVLR {i + 1} of {n_evlrs} (record length {length}) runs past the end of "
                              f"the file ({size} bytes)")


def _laz_count(f, name: str, size: int, offset: int, record_length: int, count: int, laszip: bytes) -> int:
    """Points held by the LAZ data at `offset`, from its chunk table (see the module docstring)."""
    import lazrs

    try:
        vlr = lazrs.LazVlr(laszip)
        chunk_size, variable = vlr.chunk_size(), vlr.uses_variable_size_chunks()
        item_size = vlr.item_size()
    except Exception as err:  # noqa: BLE001 (lazrs raises its own error type and ValueError)
        raise _fail(name, f"corrupt LASzip VLR ({err})") from None
    if item_size != record_length:
        raise _fail(name, f"LASzip VLR items take {item_size} bytes, the point data record length is "
                          f"{record_length}")
    if not variable and chunk_size == 0:
        raise _fail(name, "LASzip VLR has a chunk size of 0")
    if not variable and chunk_size > max(count, MAX_IDLE_CHUNK_POINTS):
        # lazrs's parallel decoder allocates chunk_size points per chunk, whatever the count
        raise _fail(name, f"LASzip chunk size {chunk_size} is larger than the {count} points of the file")
    f.seek(offset)
    raw = f.read(8)
    if len(raw) < 8:
        raise _fail(name, "truncated LAZ data: no chunk table offset after the offset to point data")
    (table_at,) = struct.unpack("<q", raw)
    if table_at == -1 and size >= offset + 16:  # written by a streaming LASzip: offset at the end
        f.seek(size - 8)
        (table_at,) = struct.unpack("<q", f.read(8))
    data_bytes = table_at - offset - 8
    if data_bytes < 0 or table_at + 8 > size:
        raise _fail(name, f"truncated or corrupt LAZ data: chunk table offset {table_at} lies outside the "
                          f"file ({size} bytes)")
    f.seek(table_at + 4)
    (n_chunks,) = struct.unpack("<I", f.read(4))
    if n_chunks > data_bytes:  # a chunk takes at least one byte
        raise _fail(name, f"truncated or corrupt LAZ data: chunk table lists {n_chunks} chunks, more than "
                          f"{data_bytes} bytes of points can hold")
    if count > MAX_LAZ_POINTS_PER_BYTE * max(data_bytes, 1):
        raise _fail(name, f"header says {count} points, far more than {data_bytes} bytes of LAZ data can "
                          "hold")
    f.seek(table_at)
    try:
        table = lazrs.read_chunk_table_only(io.BytesIO(f.read(size - table_at)), vlr)
    except Exception as err:  # noqa: BLE001
        raise _fail(name, f"truncated or corrupt LAZ chunk table ({err})") from None
    if len(table) != n_chunks or sum(b for _, b in table) > data_bytes:
        raise _fail(name, "truncated or corrupt LAZ chunk table (its chunks do not fit the point data)")
    if not table:
        return 0
    layers = _layer_count(laszip)
    if layers is not None:
        return _layered_count(f, name, offset, record_length, layers, table, None if variable else chunk_size)
    if variable:
        return sum(int(n) for n, _ in table)
    before = (n_chunks - 1) * chunk_size
    start = offset + 8 + sum(b for _, b in table[:-1])
    f.seek(start)
    stored = f.read(table[-1][1])
    limit = min(chunk_size, MAX_LAZ_POINTS_PER_BYTE * max(len(stored), 1))
    claimed = count - before
    if 1 <= claimed <= limit:
        packed = _recompressed(f, offset, laszip, vlr, n_chunks, before, claimed, record_length)
        if packed == stored:
            return count
        if packed is None and _recompressed(f, offset, laszip, vlr, n_chunks, before, 1, record_length) is None:
            return count  # not even one point decodes: corrupt data, which the full read reports
    found = _search_last_chunk(f, offset, laszip, vlr, n_chunks, before, limit, record_length, stored)
    if found is None:
        if not before < count <= before + chunk_size:
            raise _fail(name, f"header says {count} points, the LAZ chunk table holds {n_chunks} chunks of "
                              f"up to {chunk_size}")
        return count  # an encoder lazrs does not reproduce: no evidence against the header
    return before + found


# Layers per LASzip item of the 1.4 ("layered", item version 3+) point formats 6-10; BYTE14
# (extra bytes) has one layer per byte.
_LAYERS = {10: 9, 11: 1, 12: 2, 13: 1}
_BYTE14 = 14


def _layer_count(laszip: bytes) -> int | None:
    """Layers per chunk of a layered (point formats 6-10) LASzip VLR, or None for formats 0-5."""
    if len(laszip) < 34:
        return None
    (n_items,) = struct.unpack_from("<H", laszip, 32)
    if len(laszip) < 34 + 6 * n_items or n_items == 0:
        return None
    items = [struct.unpack_from("<HHH", laszip, 34 + 6 * i) for i in range(n_items)]
    if items[0][0] != 10 or any(version < 3 for _, _, version in items):
        return None
    if any(kind not in _LAYERS and kind != _BYTE14 for kind, _, _ in items):
        return None
    return sum(size if kind == _BYTE14 else _LAYERS[kind] for kind, size, _ in items)


def _layered_count(f, name: str, offset: int, record_length: int, layers: int, table,
                   chunk_size: int | None) -> int:
    """Points of layered LAZ data: each chunk starts with its first point (raw), its point count
    and the byte size of each layer (LASzip 1.4 "layered chunks"); sizes that overrun the chunk,
    and counts above the chunk size or 1,000 points per byte, are refused here, before lazrs
    would try to read (or --trust-data to allocate) them."""
    head = record_length + 4 + 4 * layers
    pos, total = offset + 8, 0
    for i, (_, size) in enumerate(table):
        f.seek(pos)
        raw = f.read(head)
        if len(raw) < head or size < head:
            raise _fail(name, f"truncated or corrupt LAZ data: chunk {i + 1} of {len(table)} is shorter than "
                              "its header")
        (count,) = struct.unpack_from("<I", raw, record_length)
        sizes = struct.unpack_from(f"<{layers}I", raw, record_length + 4)
        if head + sum(sizes) > size:
            raise _fail(name, f"truncated or corrupt LAZ data: the layers of chunk {i + 1} of {len(table)} "
                              f"take {head + sum(sizes)} bytes, the chunk {size}")
        if count > MAX_LAZ_POINTS_PER_BYTE * size or (chunk_size is not None and count > chunk_size):
            raise _fail(name, f"truncated or corrupt LAZ data: chunk {i + 1} of {len(table)} says it holds "
                              f"{count} points in {size} bytes")
        total += count
        pos += size
    return total


def _recompressed(f, offset: int, laszip: bytes, vlr, n_chunks: int, before: int, n: int,
                  record_length: int) -> bytes | None:
    """The last chunk decompressed as `n` points and compressed again (chunk bytes only)."""
    import lazrs

    f.seek(offset)
    try:
        decompressor = lazrs.LasZipDecompressor(f, laszip)
        decompressor.seek(before)
        points = bytearray(n * record_length)
        decompressor.decompress_many(points)
        packed = bytes(lazrs.compress_points(vlr, bytes(points), False))
    except Exception:  # noqa: BLE001 (garbage past the real points: no reproduction)
        return None
    (table_at,) = struct.unpack_from("<q", packed, 0)
    return packed[8:table_at]


def _search_last_chunk(f, offset, laszip, vlr, n_chunks, before, limit, record_length, stored) -> int | None:
    """The point count in 1..limit whose recompression gives `stored`, or None.

    The recompressed length grows with the count; bisect for the first count whose length
    reaches `len(stored)`, then try the few counts of that length (at most 16 + log2(limit)
    recompressions of at most one chunk).
    """
    def length(n: int) -> float:
        packed = _recompressed(f, offset, laszip, vlr, n_chunks, before, n, record_length)
        return math.inf if packed is None else len(packed)

    lo, hi = 1, limit
    while lo < hi:
        mid = (lo + hi) // 2
        if length(mid) < len(stored):
            lo = mid + 1
        else:
            hi = mid
    for n in range(lo, min(lo + 16, limit) + 1):
        packed = _recompressed(f, offset, laszip, vlr, n_chunks, before, n, record_length)
        if packed == stored:
            return n
        if packed is None or len(packed) > len(stored):
            break
    return None


__all__ = ["Layout", "MAX_LAZ_POINTS_PER_BYTE", "check_layout", "check_regular_file"]
