"""Fuzzing COPC hierarchies: a survey indexes a COPC file (`gfjax.survey.catalog.index_file`)
and reads its tile windows through its octree (`Entry.within`, `gfjax.io.copc.Reader.within`),
which rest on the hierarchy's keys, byte ranges and point counts and on the info record's cube.
Whatever those hold, each window gives exactly the points a full read finds in it, with their
file indices, or an `InputError` naming the file; never another exception, never a hang (each
case has `HANG_S`).

The seed is a small COPC file whose hierarchy is split in pages (copc-lib writes one): the
root page holds the root node and a child-page entry (point count -1) for each level-1 node
with descendants; that page holds the node and its subtree. Its mutations: an entry's key,
offset, byte size or point count set to an edge value (0, -1, int32 limits, 2**63, ...) or to
a place in the file (a page, its own page, another entry's value, the point data, the chunk
table, the info record, the end of the file); an entry given another's key (a duplicate, an
ancestor, a page's node); two entries' chunks swapped; the info record's center, half size
and spacing NaN, infinite, 0, negative or huge, its root page's offset and size likewise.
"""
from __future__ import annotations

import io
import struct
from typing import NamedTuple

import laspy
import numpy as np
import pytest

pytest.importorskip("copclib")
from fuzz_deadline import Hang, deadline  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from gfjax.errors import InputError  # noqa: E402
from gfjax.io import copc  # noqa: E402
from gfjax.io.cloud import Cloud  # noqa: E402
from gfjax.survey import catalog  # noqa: E402

HANG_S = 5.0                    # one case's reads, at most [s]: far more than a good one takes
_ENTRY = struct.Struct("<iiiiQii")
_VLR_HEADER, _EVLR_HEADER = 54, 60
# where each field of an entry lies in its 32 bytes, and how it is stored
_FIELDS = {"level": (0, "<i"), "x": (4, "<i"), "y": (8, "<i"), "z": (12, "<i"), "offset": (16, "<Q"),
           "byte_size": (24, "<i"), "point_count": (28, "<i")}
# the info record's fields (offset into its data, format)
_INFO = {"center_x": (0, "<d"), "center_y": (8, "<d"), "center_z": (16, "<d"), "halfsize": (24, "<d"),
         "spacing": (32, "<d"), "root_offset": (40, "<Q"), "root_size": (48, "<Q")}
INT32 = [0, 1, -1, -2, 2**31 - 1, -2**31]
UINT64 = [0, 1, 2**63, 2**64 - 1]
DOUBLES = [float("nan"), float("inf"), float("-inf"), 0.0, -0.0, -1.0, 1e-300, 1e300]


class Layout(NamedTuple):
    """Where a seed's COPC records lie [bytes from the file's start]."""

    size: int                            # the file
    info: int                            # the info record's data
    points: tuple[int, int]              # the nodes' chunks: first byte, chunk table
    pages: tuple[tuple[int, int], ...]   # (offset, bytes) of each hierarchy page, the root's first
    entries: tuple[int, ...]             # each entry of every page


def _descends(key, top) -> bool:
    shift = key[0] - top[0]
    return shift > 0 and all(k >> shift == t for k, t in zip(key[1:], top[1:]))


def paged(data: bytes) -> tuple[bytes, Layout]:
    """`data`, a COPC file with one hierarchy page (its only EVLR), with the hierarchy split in
    pages (see the module's docstring), and where its records lie."""
    header_size, to_points = struct.unpack_from("<HI", data, 94)
    evlr_start, n_evlrs = struct.unpack_from("<QI", data, 235)
    info = header_size + _VLR_HEADER
    root, root_size = struct.unpack_from("<QQ", data, info + 40)
    assert n_evlrs == 1 and root == evlr_start + _EVLR_HEADER and root + root_size == len(data)
    entries = [_ENTRY.unpack_from(data, root + i) for i in range(0, root_size, _ENTRY.size)]
    tops = [e for e in entries if e[0] == 1 and any(_descends(f[:4], e[:4]) for f in entries)]
    subpages = [[top, *(e for e in entries if _descends(e[:4], top[:4]))] for top in tops]
    in_subpage = {e[:4] for page in subpages for e in page}
    root_entries = [e for e in entries if e[:4] not in in_subpage]
    at = root + _ENTRY.size * (len(root_entries) + len(tops))
    pages = [(root, at - root)]
    for top, page in zip(tops, subpages):
        root_entries.append((*top[:4], at, _ENTRY.size * len(page), -1))
        pages.append((at, _ENTRY.size * len(page)))
        at += _ENTRY.size * len(page)
    body = b"".join(_ENTRY.pack(*e) for e in [*root_entries, *(e for page in subpages for e in page)])
    evlr = bytearray(data[evlr_start:root])
    struct.pack_into("<Q", evlr, 20, len(body))
    out = bytearray(data[:evlr_start] + evlr + body)
    struct.pack_into("<Q", out, info + 48, pages[0][1])
    chunk_table = struct.unpack_from("<q", data, to_points)[0]
    layout = Layout(len(out), info, (to_points + 8, chunk_table), tuple(pages),
                    tuple(range(root, len(out), _ENTRY.size)))
    return bytes(out), layout


def _seed_las() -> laspy.LasData:
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 100, (3000, 2)) + (300_000.0, 4_100_000.0)
    return Cloud.from_xyz(np.column_stack([xy, rng.uniform(40, 60, 3000)])).las


class Seed(tuple):
    """(bytes of the paged seed, its `Layout`, its points as a full read gives them)."""

    def __repr__(self) -> str:          # in hypothesis's reports
        return f"Seed({len(self[0]):,} bytes, {len(self[1].pages)} hierarchy pages, {len(self[2]):,} points)"


@pytest.fixture(scope="module")
def seed(tmp_path_factory):
    from copc_writer import write_copc

    path = tmp_path_factory.mktemp("copc") / "seed.copc.laz"
    written = write_copc(_seed_las(), path, depth=3, capacity=200)
    return Seed((*paged(path.read_bytes()), written.points))


def _value(layout: Layout, data: bytes, entry: int, spec):
    """An edge value for a field: an int, or a place in the layout ("page", k), ("entry", k,
    field), ("end", delta), ("points", 0 or 1), ("info",)."""
    if isinstance(spec, int):
        return spec
    kind, *rest = spec
    if kind == "page":
        return layout.pages[rest[0] % len(layout.pages)][0]
    if kind == "own page":
        return max(p for p, _ in layout.pages if p <= layout.entries[entry])
    if kind == "entry":
        other = layout.entries[rest[0] % len(layout.entries)]
        at, fmt = _FIELDS[rest[1]]
        return struct.unpack_from(fmt, data, other + at)[0]
    if kind == "end":
        return layout.size + rest[0]
    if kind == "points":
        return layout.points[rest[0]]
    return layout.info


def mutate(data: bytes, layout: Layout, mutations) -> bytes:
    out = bytearray(data)
    for mutation in mutations:
        kind, *args = mutation
        if kind == "field":
            i, field, spec = args
            i %= len(layout.entries)
            at, fmt = _FIELDS[field]
            value = _value(layout, bytes(out), i, spec)
            value = value % 2**64 if fmt == "<Q" else (value + 2**31) % 2**32 - 2**31
            struct.pack_into(fmt, out, layout.entries[i] + at, value)
        elif kind == "key":             # an entry's key made another's (a duplicate, an ancestor, a page's)
            i, j = (k % len(layout.entries) for k in args)
            out[layout.entries[i]:layout.entries[i] + 16] = out[layout.entries[j]:layout.entries[j] + 16]
        elif kind == "swap":            # two entries' offsets, sizes and counts swapped
            i, j = (layout.entries[k % len(layout.entries)] for k in args)
            a, b = bytes(out[i + 16:i + 32]), bytes(out[j + 16:j + 32])
            out[i + 16:i + 32], out[j + 16:j + 32] = b, a
        else:                           # the info record
            field, value = args
            at, fmt = _INFO[field]
            if fmt == "<Q" and not isinstance(value, int):
                value = _value(layout, bytes(out), 0, value)
            struct.pack_into(fmt, out, layout.info + at, value % 2**64 if fmt == "<Q" else value)
    return bytes(out)


_index = st.integers(0, 63)
_place = st.one_of(st.tuples(st.just("page"), _index), st.just(("own page",)),
                   st.tuples(st.just("entry"), _index, st.sampled_from(["offset", "byte_size", "point_count"])),
                   st.tuples(st.just("end"), st.sampled_from([-32, -1, 0, 1])),
                   st.tuples(st.just("points"), st.integers(0, 1)), st.just(("info",)))
_field = st.one_of(
    st.tuples(st.just("field"), _index, st.sampled_from(["level", "x", "y", "z"]),
              st.sampled_from([*INT32, 2, 3, 4, 30, 31, 32, 64])),
    st.tuples(st.just("field"), _index, st.just("offset"), st.sampled_from(UINT64) | _place),
    st.tuples(st.just("field"), _index, st.sampled_from(["byte_size", "point_count"]),
              st.sampled_from([*INT32, 32, 3000, 3001]) | _place))
_info = st.one_of(
    st.tuples(st.just("info"), st.sampled_from(["center_x", "center_y", "center_z", "halfsize", "spacing"]),
              st.sampled_from(DOUBLES) | st.floats(-1e6, 1e6)),
    st.tuples(st.just("info"), st.sampled_from(["root_offset", "root_size"]),
              st.sampled_from([*UINT64, 32, 31, 33]) | _place))
MUTATIONS = st.lists(_field | _info | st.tuples(st.sampled_from(["key", "swap"]), _index, _index),
                     min_size=1, max_size=3)
# a window as fractions of the points' extent: lower left, upper right
BOXES = st.lists(st.tuples(st.floats(-0.1, 1.1), st.floats(-0.1, 1.1), st.floats(0, 0.6), st.floats(0, 0.6)),
                 min_size=1, max_size=2)


def windows(points, boxes):
    """[(lo, hi)] of each box, as [m] (the seed's units), and the whole extent."""
    x, y = np.asarray(points.x), np.asarray(points.y)
    low, span = np.array([x.min(), y.min()]), np.array([np.ptp(x), np.ptp(y)])
    out = [(low + span * (fx, fy), low + span * (fx + w, fy + h)) for fx, fy, w, h in boxes]
    return [*out, (low - 1.0, low + span + 1.0)]


def read_windows(path, points, boxes) -> None:
    """`path` indexed as a survey's file (its hierarchy checked, every point against its node)
    and every window's points read through its octree (`Entry.within`), checked against
    `points` (a full read of the seed); or an `InputError` naming `path`."""
    x, y = np.asarray(points.x), np.asarray(points.y)
    try:
        with deadline(HANG_S):
            entry = catalog.index_file(0, path, path.with_suffix(".npy"), units="m").entry
            assert entry.store is None and entry.n_points == len(points)
            for lo, hi in windows(points, boxes):
                index, records = entry.within(lo, hi)
                want = np.flatnonzero((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]))
                np.testing.assert_array_equal(index, want)
                assert records.tobytes() == catalog.to_records(points[want], entry.scale_m).tobytes()
    except InputError as err:
        assert str(path) in str(err), err
    except Hang as hang:            # a failure hypothesis shrinks (it passes a BaseException on)
        raise AssertionError(f"{path}: {hang}") from None


def test_the_paged_seed_reads_every_window_as_a_full_read(seed, tmp_path):
    data, layout, points = seed
    path = tmp_path / "paged.copc.laz"
    path.write_bytes(data)
    nodes = copc.hierarchy(io.BytesIO(data), *layout.pages[0], name=str(path))
    assert len(layout.pages) > 2 and sum(n.point_count for n in nodes) == len(points)
    with copc.Reader(path) as reader:
        assert reader.n_points == len(points)
        index, _ = reader.within(*windows(points, [(0.1, 0.2, 0.3, 0.3)])[0])
        assert 0 < index.size and reader.read_points < 0.5 * len(points)
    read_windows(path, points, [(0.1, 0.2, 0.3, 0.3), (0.5, -0.1, 0.01, 1.2)])


@settings(max_examples=200, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(mutations=MUTATIONS, boxes=BOXES)
def test_a_mutated_copc_hierarchy_reads_every_window_exactly_or_is_refused(seed, tmp_path, mutations, boxes):
    data, layout, points = seed
    path = tmp_path / "case.copc.laz"
    path.write_bytes(mutate(data, layout, mutations))
    read_windows(path, points, boxes)
