"""COPC output (`gfjax.io.copc_writer`): the octree's nodes against a brute-force loop, and a
written file that laspy's COPC reader reads whole, with every point, dimension and record of
the input."""
from __future__ import annotations

import datetime

import laspy
import numpy as np
import pytest
from conftest import shared_file
from test_las import SHARED_FILES, synthetic_las

from gfjax.errors import InputError
from gfjax.io import copc, copc_writer
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud

pytest.importorskip("copclib")


def brute_force_nodes(xyz, center, halfsize, *, node_points, max_depth, seed=0):
    """One point at a time, in the writer's visiting order: the shallowest node of its path
    with room, or the deepest."""
    unit = (xyz - (center - halfsize)) / (2 * halfsize)
    members: dict[tuple, list[int]] = {}
    for i in np.random.default_rng(seed).permutation(len(xyz)):
        for d in range(max_depth + 1):
            cell = tuple(int(c) for c in np.clip(np.floor(unit[i] * (1 << d)), 0, (1 << d) - 1))
            key = (d, *cell)
            if len(members.get(key, [])) < node_points or d == max_depth:
                members.setdefault(key, []).append(int(i))
                break
    return sorted((key, np.sort(np.asarray(index))) for key, index in members.items())


@pytest.mark.parametrize("case", ["uniform", "ground-and-trees", "stacked", "one-point", "two-points"])
def test_octree_nodes_are_the_brute_force_loops(case):
    rng = np.random.default_rng(3)
    xyz = {"uniform": rng.uniform(0, 100, (3000, 3)),
           "ground-and-trees": np.column_stack([rng.uniform(0, 100, (3000, 2)), rng.exponential(2, 3000)]),
           "stacked": np.concatenate([np.full((900, 3), 7.25), rng.uniform(0, 100, (300, 3))]),
           "one-point": np.array([[5.0, 5.0, 5.0]]),
           "two-points": np.array([[0.0, 0.0, 0.0], [100.0, 100.0, 100.0]])}[case]
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    center, halfsize = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1.0) * (1 + 1e-9)
    got = copc_writer.octree_nodes(xyz, center, halfsize, node_points=40, max_depth=5)
    want = brute_force_nodes(xyz, center, halfsize, node_points=40, max_depth=5)
    assert [key for key, _ in got] == [key for key, _ in want]
    for (key, a), (_, b) in zip(got, want, strict=True):
        np.testing.assert_array_equal(a, b, err_msg=str(key))
    assert np.array_equal(np.sort(np.concatenate([i for _, i in got])), np.arange(len(xyz)))
    if case == "stacked":              # the stack fills every node of its path, the deepest holds the rest
        assert max(len(i) for _, i in got) >= 900 - 5 * 40


def _written(las: laspy.LasData, path, **options) -> tuple[laspy.LasData, np.ndarray]:
    order = copc_writer.write(las, path, name=str(path), wkt=None, **options)
    return laspy.read(path), order


def _records(vlrs, user_id: str) -> list[tuple]:
    return [(v.user_id, v.record_id, v.record_data_bytes()) for v in vlrs if v.user_id == user_id]


@pytest.mark.parametrize("point_format,version", [(0, "1.2"), (1, "1.2"), (2, "1.3"), (3, "1.2"), (6, "1.4"),
                                                  (7, "1.4"), (8, "1.4")])
def test_a_copc_file_holds_every_point_dimension_and_record(point_format, version, tmp_path):
    las = synthetic_las(point_format, version, n=3000)
    src = tmp_path / "src.las"
    las.write(src)
    las = laspy.read(src)                          # as stored: extra-bytes min/max filled in
    las.header.system_identifier, las.header.generating_software = "a scanner", "a producer"
    las.header.creation_date = datetime.date(2021, 3, 9)
    las.header.file_source_id = 4321
    out = tmp_path / "out.copc.laz"
    back, order = _written(las, out, node_points=200, max_depth=4)

    assert copc.is_copc(out) and back.header.version.minor == 4
    assert back.header.point_format.id == copc_writer.FORMATS[point_format]
    with laspy.CopcReader.open(out) as reader:
        assert len(reader.query()) == len(las.points)
    with copc.Reader(out) as reader:
        assert reader.n_points == len(las.points)
    np.testing.assert_array_equal(np.sort(order), np.arange(len(las.points)))
    for name in las.point_format.dimension_names:
        if name == "scan_angle_rank":          # in 0.006 degree steps: the whole degrees come back rounded
            np.testing.assert_array_equal(np.round(np.asarray(back.scan_angle) * copc_writer.SCAN_ANGLE_STEP_DEG),
                                          np.asarray(las.scan_angle_rank)[order], err_msg=name)
        else:
            np.testing.assert_array_equal(np.asarray(back[name]), np.asarray(las[name])[order], err_msg=name)
    np.testing.assert_array_equal(back.header.scales, las.header.scales)
    np.testing.assert_array_equal(back.header.offsets, las.header.offsets)
    stored = las.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs
    assert [bytes(s) for s in back.header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs] == list(map(bytes, stored))
    user = _records([*las.header.vlrs, *(las.evlrs or [])], "gfjax_test")
    assert len(user) == 1 + (version == "1.4") and _records(back.evlrs, "gfjax_test") == user
    assert (back.header.system_identifier, back.header.generating_software) == ("a scanner", "a producer")
    assert back.header.creation_date == datetime.date(2021, 3, 9) and back.header.file_source_id == 4321
    assert back.header.uuid == las.header.uuid
    np.testing.assert_array_equal(back.header.mins, [np.asarray(back[a]).min() for a in "xyz"])
    by_return = np.bincount(np.asarray(back.return_number), minlength=16)[1:16]
    np.testing.assert_array_equal(back.header.number_of_points_by_return, by_return)


def test_the_crs_is_the_inputs_wkt_as_read_or_made_from_its_geotiff_keys(tmp_path):
    cloud = Cloud.from_xyz(np.random.default_rng(0).uniform(0, 50, (500, 3)) + [500_000, 5_000_000, 0])
    las = cloud.las
    las.header.add_crs(__import__("pyproj").CRS.from_epsg(32632))
    src = tmp_path / "wkt.las"
    las.write(src)
    read = las_io.read(src)
    out = las_io.write(read.with_ground(np.ones(len(read.xyz_m), bool)), tmp_path / "wkt.copc.laz")
    assert laspy.read(out).header.parse_crs().to_epsg() == 32632
    wkt = [v.string for v in laspy.read(src).header.vlrs if isinstance(v, laspy.vlrs.known.WktCoordinateSystemVlr)]
    back = laspy.read(out)                                   # copc-lib writes it as an EVLR
    got = [v.string for v in [*back.header.vlrs, *back.evlrs] if isinstance(v, laspy.vlrs.known.WktCoordinateSystemVlr)]
    assert got == wkt

    keys = laspy.LasHeader(point_format=1, version="1.2")      # a LAS 1.2 file states its CRS in GeoTIFF keys
    keys.add_crs(__import__("pyproj").CRS.from_epsg(32632))
    old = laspy.LasData(keys)
    old.points = laspy.ScaleAwarePointRecord.zeros(100, header=keys)
    old.x, old.y, old.z = np.arange(100.0) + 500_000, np.arange(100.0) + 5_000_000, np.zeros(100)
    old.write(tmp_path / "keys.las")
    read = las_io.read(tmp_path / "keys.las")
    out = las_io.write(read.with_ground(np.ones(100, bool)), tmp_path / "keys.copc.laz")
    back = laspy.read(out)
    assert back.header.parse_crs().to_epsg() == 32632
    assert not any(v.record_id == 34735 for v in [*back.header.vlrs, *back.evlrs])   # WKT only, as COPC asks


@pytest.mark.parametrize("point_format", [4, 5, 9, 10])
def test_a_waveform_point_format_is_refused_naming_the_file(point_format, tmp_path):
    header = laspy.LasHeader(point_format=point_format, version="1.4" if point_format > 5 else "1.3")
    with pytest.raises(InputError, match=rf"in.las: point format {point_format} carries waveform packets.*"
                                         r"write .*out.copc.laz as .laz"):
        copc_writer.check_writable(header, tmp_path / "out.copc.laz", name="in.las")
    copc_writer.check_writable(header, tmp_path / "out.laz", name="in.las")      # plain LAZ holds them


def test_a_failed_copc_write_leaves_no_file(tmp_path, monkeypatch):
    cloud = Cloud.from_xyz(np.random.default_rng(0).uniform(0, 50, (500, 3)))

    def fail(*args, **kwargs):
        raise RuntimeError("No space left on device")

    import copclib
    monkeypatch.setattr(copclib.FileWriter, "Close", fail)
    with pytest.raises(InputError, match=r"out.copc.laz: cannot write COPC \(No space left on device\)"):
        las_io.write(cloud, tmp_path / "out.copc.laz")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.data
@pytest.mark.parametrize("relative", SHARED_FILES)
def test_every_shared_file_written_as_copc_keeps_every_point_and_dimension(relative, tmp_path):
    cloud = las_io.read(shared_file(relative))
    out = tmp_path / "out.copc.laz"
    order = copc_writer.write(cloud.las, out, name=str(out), wkt=None)
    back = laspy.read(out)
    with laspy.CopcReader.open(out) as reader:
        assert len(reader.query()) == len(cloud.las.points)
    for name in cloud.las.point_format.dimension_names:
        want = np.asarray(cloud.las[name])[order]
        if name == "scan_angle_rank":
            np.testing.assert_array_equal(np.round(np.asarray(back.scan_angle) * copc_writer.SCAN_ANGLE_STEP_DEG), want)
        else:
            np.testing.assert_array_equal(np.asarray(back[name]), want, err_msg=name)
