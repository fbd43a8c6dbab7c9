"""COPC input: a box's points read from the octree nodes that meet it, with their file indices;
a survey of COPC files labels as its LAS copies; outputs are plain LAZ with every point kept."""
from __future__ import annotations

import laspy
import numpy as np
import pytest

from gfjax import smrf, survey
from gfjax.cli.main import main
from gfjax.errors import InputError
from gfjax.io import copc
from gfjax.io.cloud import Cloud
from gfjax.tiling.tiles import Tiling

pytest.importorskip("copclib")
from copc_writer import write_copc  # noqa: E402

SMALL_TILES = Tiling(tile_size_m=40.0, buffer_m=8.0)


def hills(seed=0, n=20_000, size=(160.0, 120.0), origin=(300_000.0, 4_100_000.0)):
    """Rolling ground with a few 6 m boxes on it, classes 2 and 6, one noise point (7)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, size, (n, 2))
    z = 50 + 3 * np.sin(xy[:, 0] / 25) + 2 * np.cos(xy[:, 1] / 30) + rng.normal(0, 0.03, n)
    box = (np.abs((xy[:, 0] % 40) - 20) < 6) & (np.abs((xy[:, 1] % 40) - 20) < 6)
    z[box] += 6.0
    cls = np.where(box, 6, 2).astype(np.uint8)
    cls[7] = 7
    return Cloud.from_xyz(np.column_stack([xy + origin, z]), classification=cls).las


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """A COPC file and its LAS copy (the same points in the same order)."""
    folder = tmp_path_factory.mktemp("copc")
    written = write_copc(hills(), folder / "hills.copc.laz")
    written.write(folder / "hills.las")
    return folder / "hills.copc.laz", folder / "hills.las"


def test_a_copc_file_is_told_from_plain_laz(pair):
    assert copc.is_copc(pair[0]) and not copc.is_copc(pair[1])


@pytest.mark.parametrize("box", [(30, 20, 70, 55), (-5, -5, 3, 200), (0, 0, 160, 120), (500, 500, 600, 600),
                                 (80, 60, 80, 60)], ids=["inside", "edge", "all", "outside", "a-point-wide"])
def test_within_gives_the_box_points_with_their_file_indices(pair, box):
    whole = laspy.read(pair[1])
    lo = np.asarray(whole.header.mins[:2]) + box[:2]
    hi = np.asarray(whole.header.mins[:2]) + box[2:]
    x, y = np.asarray(whole.x), np.asarray(whole.y)
    want = np.flatnonzero((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]))
    with copc.Reader(pair[0]) as reader:
        index, points = reader.within(lo, hi)
        assert reader.n_points == len(whole.points)
        np.testing.assert_array_equal(index, want)
        np.testing.assert_array_equal(points.array, whole.points.array[want])
        if box == (30, 20, 70, 55):
            assert reader.read_points < 0.5 * reader.n_points       # only the nodes that meet the box


@pytest.mark.slow
def test_a_survey_of_copc_files_labels_as_its_las_copies(tmp_path):
    las = hills(seed=1, n=30_000, size=(240.0, 120.0))
    x = np.asarray(las.x)
    cut = np.quantile(x, 0.5)
    copcs, plain = [], []
    for k, keep in enumerate((x < cut, x >= cut)):
        part = laspy.LasData(las.header, las.points[keep].copy())
        written = write_copc(part, tmp_path / f"part{k}.copc.laz")
        written.write(tmp_path / f"part{k}.las")
        copcs.append(tmp_path / f"part{k}.copc.laz")
        plain.append(tmp_path / f"part{k}.las")
    stores = tmp_path / "stores"
    stores.mkdir()
    catalog = survey.index(copcs, stores)
    assert all(entry.store is None for entry in catalog.entries) and not list(stores.iterdir())
    got = [r.ground for _, r in survey.filtered(copcs, smrf, tmp_path / "stores", tiling=SMALL_TILES)]
    (tmp_path / "stores2").mkdir()
    want = [r.ground for _, r in survey.filtered(plain, smrf, tmp_path / "stores2", tiling=SMALL_TILES)]
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    assert any(np.any(g) for g in got) and any(np.any(~g) for g in got)


@pytest.mark.slow
def test_filtering_a_copc_file_writes_plain_laz_with_every_point(pair, tmp_path):
    source = laspy.read(pair[0])
    outs = {"copc": tmp_path / "copc.laz", "copc-out-of-core": tmp_path / "ooc.laz", "las": tmp_path / "las.laz"}
    assert main(["filter", str(pair[0]), "-o", str(outs["copc"])]) == 0
    assert main(["filter", str(pair[0]), "-o", str(outs["copc-out-of-core"]), "--out-of-core"]) == 0
    assert main(["filter", str(pair[1]), "-o", str(outs["las"])]) == 0
    want = laspy.read(outs["las"]).classification
    for name in ("copc", "copc-out-of-core"):
        back = laspy.read(outs[name])
        assert not copc.is_copc(outs[name]), name
        assert not any(v.user_id == "copc" for v in back.evlrs or []), name
        for dim in source.point_format.dimension_names:
            if dim != "classification":
                np.testing.assert_array_equal(back[dim], source[dim], err_msg=f"{name} {dim}")
        np.testing.assert_array_equal(back.classification, want, err_msg=name)


def test_a_copc_file_whose_data_is_cut_is_named(pair, tmp_path):
    """Its second half zeroed: the hierarchy (at the end) or the nodes' data no longer read."""
    cut = tmp_path / "cut.copc.laz"
    data = pair[0].read_bytes()
    cut.write_bytes(data[:len(data) // 2] + bytes(len(data) - len(data) // 2))
    with pytest.raises(InputError, match="cut.copc.laz"):
        with copc.Reader(cut) as reader:
            reader.within(np.array([-1e12, -1e12]), np.array([1e12, 1e12]))


def _with_root_entry(data: bytes, offset: int, size: int, points: int) -> tuple[bytes, int]:
    """`data` with the root node's hierarchy entry (key 0, 0, 0, 0) rewritten."""
    import io
    import struct

    info = laspy.CopcReader(io.BytesIO(data)).copc_info
    root, length = info.hierarchy_root_offset, info.hierarchy_root_size
    blob = bytearray(data)
    for at in range(root, root + length, 32):
        if struct.unpack_from("<iiii", blob, at) == (0, 0, 0, 0):
            struct.pack_into("<Qii", blob, at + 16, offset, size, points)
            return bytes(blob), root
    raise AssertionError("no root entry")


def test_a_copc_hierarchy_page_that_names_itself_is_refused_not_followed_for_ever(pair, tmp_path):
    """A survey reads COPC files box by box through their hierarchy (`copc.Reader`): a root
    entry that points at its own page, or at a page past the end, is bad input, not a hang."""
    import io

    data = pair[0].read_bytes()
    info = laspy.CopcReader(io.BytesIO(data)).copc_info
    looped, root = _with_root_entry(data, info.hierarchy_root_offset, info.hierarchy_root_size, -1)
    path = tmp_path / "loop.copc.laz"
    path.write_bytes(looped)
    with pytest.raises(InputError, match=f"loop.copc.laz: its COPC hierarchy page at byte {root:,} is reached "
                                         r"twice \(a loop\)"):
        copc.Reader(path)
    outside, _ = _with_root_entry(data, len(data) - 8, 64, -1)
    path.write_bytes(outside)
    with pytest.raises(InputError, match="lies outside the file"):
        copc.Reader(path)


def _entry_at(data: bytes) -> dict[tuple[int, int, int, int], int]:
    """Byte offset of each entry of a one-page COPC hierarchy, by voxel key."""
    import io
    import struct

    info = laspy.CopcReader(io.BytesIO(data)).copc_info
    root, length = info.hierarchy_root_offset, info.hierarchy_root_size
    return {struct.unpack_from("<iiii", data, at): at for at in range(root, root + length, 32)}


def _swap_chunks(data: bytes) -> bytes:
    """Two level-1 nodes given each other's chunk (offset, bytes, points): each key lies."""
    at = _entry_at(data)
    a, b = at[(1, 0, 0, 0)], at[(1, 1, 1, 0)]
    blob = bytearray(data)
    blob[a + 16:a + 32], blob[b + 16:b + 32] = data[b + 16:b + 32], data[a + 16:a + 32]
    return bytes(blob)


def _shift_chunk(data: bytes) -> bytes:
    """A level-1 node's chunk offset one byte late."""
    import struct

    blob = bytearray(data)
    at = _entry_at(data)[(1, 0, 0, 0)] + 16
    struct.pack_into("<Q", blob, at, struct.unpack_from("<Q", data, at)[0] + 1)
    return bytes(blob)


def _cube(field: int, value: float):
    """The info record's center x, y, z (field 0-2) or half size (3) set to `value`."""
    def edit(data: bytes) -> bytes:
        import struct

        header_size = struct.unpack_from("<H", data, 94)[0]
        blob = bytearray(data)
        struct.pack_into("<d", blob, header_size + 54 + 8 * field, value)
        return bytes(blob)

    return edit


@pytest.mark.parametrize("edit, problem", [
    (lambda data: _with_root_entry(data, 0, 32, -1)[0], r"page at byte 0 does not hold node \(0, 0, 0, 0\)"),
    (_swap_chunks, r"point [\d,]+ \(.*\) lies outside the square of its COPC octree node \(1, (0, 0|1, 1), 0\)"),
    (_shift_chunk, "its COPC hierarchy does not match its LAZ chunks: a node of"),
    (_cube(3, 0.0), "cube .* is not a cube"), (_cube(0, float("nan")), "cube .* is not a cube")],
    ids=["page-without-its-node", "chunks-swapped", "chunk-a-byte-late", "cube-of-size-0", "nan-center"])
def test_a_copc_hierarchy_that_lies_about_its_nodes_is_refused_when_indexed(pair, tmp_path, edit, problem):
    """Found by tests/reliability/test_fuzz_copc.py. Before: laspy followed a child-page entry
    whose page lacks the node for ever (a hang), and a survey's windows silently missed points
    or gave other points' indices when nodes named the wrong chunks or squares."""
    from gfjax.survey import catalog

    path = tmp_path / "lies.copc.laz"
    path.write_bytes(edit(pair[0].read_bytes()))
    with pytest.raises(InputError, match=f"lies.copc.laz: .*{problem}"):
        catalog.index_file(0, path, tmp_path / "store.npy", units="m")
    whole = laspy.read(pair[1])
    lo, hi = np.asarray(whole.header.mins[:2]), np.asarray(whole.header.mins[:2]) + 60
    with pytest.raises(InputError, match=f"lies.copc.laz: .*{problem}"):         # the windows' reader alone
        with copc.Reader(path) as reader:
            reader.within(lo, hi)
