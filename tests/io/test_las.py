"""LAS/LAZ round trips lose nothing; bad files and bad outputs raise InputError naming the file."""
from __future__ import annotations

import os
from pathlib import Path

import laspy
import numpy as np
import pytest
from conftest import SHARED_DATA, shared_file

from gfjax.errors import InputError
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud

SHARED_FILES = [
    *(f"isprs_filtertest/reference/samp{k}-utm.laz" for k in
      (12, 21, 22, 24, 31, 41, 42, 51, 52, 54, 71)),
    "isprs_filtertest/sites/CSite3_orig-utm.laz",
    "isprs_filtertest/sites/CSite4_orig-utm.laz",
    "isprs_filtertest/sites/FSite8_orig-utm.laz",
    "lasR_bcts/bcts_1.laz",
    "lasR_bcts/bcts_2.laz",
    "lidR_topography/Topography.laz",
    "pdal_autzen/autzen_trim.laz",
    "corpus/IGNF_ign-pdal-tools/Semis_2022_0906_6665_LA93_IGN69_ok.laz",
    "corpus/IGNF_ign-pdal-tools/las_with_several_extra_byte_bloc.laz",
    "corpus/IGNF_ign-pdal-tools/test_data_77050_627755_LA93_IGN69.laz",
    "corpus/IGNF_ign-pdal-tools/test_semis_2021_0382_6565_LA93_IGN69_cropped.laz",
    "corpus/IGNF_ign-pdal-tools/test_semis_2023_0292_6833_LA93_IGN69.laz",
    "corpus/IGNF_lidar-prod/St_Barth_RGAF09_UTM20N_IGN_1988_SB_subset_100m.laz",
    "corpus/LAStools_LAStools/fusa.laz",
    "corpus/PDAL_PDAL/4_6_crop.las",
    "corpus/PDAL_PDAL/hexbin-crop.las",
    "corpus/SDFIdk_DHMQC/1km_6076_548.laz",
    "corpus/brycefrank_pyfor/test.laz",
    "corpus/cran_lidaRtRee/las_chablais3.laz",
    "corpus/eEcoLiDAR_laserchicken/AHN3.laz",
    "corpus/tudelft3d_3dfier/ahn3_cropped_1.laz",
]
# Point formats and the oldest LAS version that holds them.
FORMAT_VERSIONS = [(0, "1.2"), (1, "1.2"), (2, "1.2"), (3, "1.2"), (4, "1.3"), (5, "1.3"),
                   *((f, "1.4") for f in range(6, 11))]
LASZIP = laspy.LazBackend.Laszip


def _vlr_bytes(vlrs, *, extra_bytes_stats: bool = True) -> list[tuple]:
    """(user_id, record_id, description, payload) of every VLR except LASzip's own.

    With `extra_bytes_stats=False` the optional min/max statistics of the Extra Bytes VLR are
    left out: laspy writes them before the points when LASzip compresses (formats 9/10).
    """
    out = []
    for vlr in vlrs:
        if isinstance(vlr, laspy.vlrs.known.LasZipVlr):
            continue
        if isinstance(vlr, laspy.vlrs.known.ExtraBytesVlr) and not extra_bytes_stats:
            payload = [(bytes(e.name), e.data_type, bytes(e.description), bytes(e._no_data), bytes(e._scale),
                        bytes(e._offset)) for e in vlr.extra_bytes_structs]
        else:
            payload = bytes(vlr.record_data_bytes() if hasattr(vlr, "record_data_bytes") else vlr.record_data)
        out.append((vlr.user_id, vlr.record_id, vlr.description, payload))
    return out


def assert_same_las(expected: laspy.LasData, actual: laspy.LasData) -> None:
    """Every point dimension (extra bytes included), raw bytes, and the header that matters."""
    by_lazrs = expected.point_format.id not in las_io.LOSSY_WITH_LAZRS  # else LASzip compressed
    stats = by_lazrs or not actual.header.are_points_compressed
    names = list(expected.point_format.dimension_names)
    assert list(actual.point_format.dimension_names) == names
    assert actual.point_format.id == expected.point_format.id
    assert str(actual.header.version) == str(expected.header.version)
    for name in names:
        np.testing.assert_array_equal(np.asarray(actual[name]), np.asarray(expected[name]), err_msg=name)
    assert actual.points.array.tobytes() == expected.points.array.tobytes()
    np.testing.assert_array_equal(actual.header.scales, expected.header.scales)
    np.testing.assert_array_equal(actual.header.offsets, expected.header.offsets)
    assert _vlr_bytes(actual.header.vlrs, extra_bytes_stats=stats) == _vlr_bytes(expected.header.vlrs, extra_bytes_stats=stats)
    assert _vlr_bytes(actual.evlrs or []) == _vlr_bytes(expected.evlrs or [])
    assert actual.header.point_count == expected.header.point_count
    assert actual.header.system_identifier == expected.header.system_identifier
    if stats:
        assert actual.header.generating_software == expected.header.generating_software


@pytest.mark.data
@pytest.mark.parametrize("relative", SHARED_FILES)
def test_shared_file_round_trip_keeps_every_dimension(relative, tmp_path):
    src = shared_file(relative)
    cloud = las_io.read(src)
    unchanged = cloud.with_ground(cloud.classification == 2)
    out = las_io.write(unchanged, tmp_path / src.name)
    assert_same_las(cloud.las, las_io.read(out).las)
    if LASZIP.is_available():  # LASzip (the reference LAZ implementation) reads our output
        assert_same_las(cloud.las, laspy.read(out, laz_backend=LASZIP))


def test_shared_list_covers_the_data_folder():
    if not SHARED_DATA.exists():
        pytest.skip(f"shared data not found: {SHARED_DATA}")
    present = sorted(str(p.relative_to(SHARED_DATA)) for p in SHARED_DATA.rglob("*.la[sz]"))
    assert present == sorted(SHARED_FILES)


def synthetic_las(point_format: int, version: str, *, n: int = 64, seed: int = 0) -> laspy.LasData:
    """Random raw bytes in every field of `point_format`, plus three extra-bytes dimensions."""
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.add_extra_dims([laspy.ExtraBytesParams("height_above_m", np.float32, description="m"),
                           laspy.ExtraBytesParams("tag", np.uint8),
                           laspy.ExtraBytesParams("normal", "3int16")])
    header.scales = np.array([0.01, 0.01, 0.001])
    header.offsets = np.array([500_000.0, 5_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.points = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    raw = las.points.array.view(np.uint8)
    raw[:] = np.random.default_rng(seed).integers(0, 256, raw.shape, dtype=np.uint8)
    las.header.vlrs.append(laspy.VLR("gfjax_test", 7, "a VLR", b"vlr payload"))
    if version == "1.4":
        las.evlrs = laspy.vlrs.vlrlist.VLRList([laspy.VLR("gfjax_test", 8, "an EVLR", b"evlr payload " * 100)])
    return las


@pytest.mark.parametrize("point_format,version", FORMAT_VERSIONS)
@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_synthetic_round_trip_every_point_format(point_format, version, suffix, tmp_path):
    las = synthetic_las(point_format, version)
    src = tmp_path / "src.las"
    las.write(src)  # written by laspy uncompressed, read and re-written by us
    expected = laspy.read(src)  # as stored (laspy fills the extra-bytes min/max on write)
    assert len(expected.header.vlrs) == 2 and len(expected.evlrs or []) == (version == "1.4")
    assert expected.points.array.tobytes() == las.points.array.tobytes()
    cloud = las_io.read(src, units="m")
    out = las_io.write(cloud.with_ground(cloud.classification == 2), tmp_path / f"out{suffix}")
    assert_same_las(expected, las_io.read(out).las)
    if suffix == ".laz" and LASZIP.is_available() and point_format not in (4, 5):
        assert_same_las(expected, laspy.read(out, laz_backend=LASZIP))


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_extra_bytes_statistics_are_written_back_as_read(suffix, tmp_path):
    """A producer's min/max of an extra-bytes dimension (here stale: not the points' range)
    come back byte for byte; laspy alone would recompute them from the points."""
    las = synthetic_las(3, "1.2")
    src = tmp_path / "src.las"
    las.write(src)
    raw = bytearray(src.read_bytes())
    stored = laspy.read(src).header.vlrs.get("ExtraBytesVlr")[0]
    offset = raw.index(bytes(stored.extra_bytes_structs[0]))
    stale = laspy.vlrs.known.ExtraBytesStruct.from_buffer_copy(bytes(stored.extra_bytes_structs[0]))
    np.frombuffer(stale._min, dtype=np.float64)[0] = -123.5
    np.frombuffer(stale._max, dtype=np.float64)[0] = 4567.25
    raw[offset:offset + len(bytes(stale))] = bytes(stale)
    src.write_bytes(bytes(raw))
    out = las_io.write(las_io.read(src), tmp_path / f"out{suffix}")
    back = laspy.read(out).header.vlrs.get("ExtraBytesVlr")[0].extra_bytes_structs[0]
    assert (np.frombuffer(back._min, dtype=np.float64)[0], np.frombuffer(back._max, dtype=np.float64)[0]) == (-123.5, 4567.25)
    assert bytes(back) == bytes(stale)


@pytest.mark.parametrize("point_format", [9, 10])
def test_lazrs_loses_wave_packets_of_formats_9_and_10(point_format):
    """Why `write` compresses wave-packet formats with LASzip: lazrs changes these fields.

    When this fails, lazrs has been fixed and `las._LOSSY_WITH_LAZRS` can be emptied.
    """
    import io

    las = synthetic_las(point_format, "1.4")
    buffer = io.BytesIO()
    las.write(buffer, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
    buffer.seek(0)
    back = laspy.read(buffer, laz_backend=laspy.LazBackend.Lazrs)
    assert back.points.array.tobytes() != las.points.array.tobytes()


def test_laz_output_is_compressed_and_las_is_not(tmp_path):
    cloud = Cloud.from_xyz(np.random.default_rng(1).uniform(0, 100, (200, 3)))
    laz, plain = las_io.write(cloud, tmp_path / "a.laz"), las_io.write(cloud, tmp_path / "a.las")
    with laspy.open(laz) as a, laspy.open(plain) as b:
        assert a.header.are_points_compressed and not b.header.are_points_compressed
    assert_same_las(las_io.read(laz).las, las_io.read(plain).las)


# ---------------------------------------------------------------- valid edge cases (SPEC 1)

def test_one_point_and_duplicate_points_round_trip(tmp_path):
    for xyz in (np.array([[1.0, 2.0, 3.0]]), np.repeat([[10.0, 20.0, 30.0]], 5, axis=0)):
        cloud = Cloud.from_xyz(xyz, classification=np.full(len(xyz), 2, np.uint8))
        back = las_io.read(las_io.write(cloud, tmp_path / "edge.laz"))
        assert back.n_points == len(xyz)
        np.testing.assert_array_equal(back.xyz, cloud.xyz)


def test_coordinates_of_1e7_m_stay_centimetre_exact_in_local_float32(tmp_path):
    rng = np.random.default_rng(2)
    xyz = np.array([1.0e7, 1.0e7, 100.0]) + np.round(rng.uniform(0, 500, (1000, 3)), 2)
    cloud = las_io.read(las_io.write(Cloud.from_xyz(xyz, scale=0.01), tmp_path / "far.laz"))
    local, origin = cloud.local_xyz_m()
    assert local.dtype == np.float32
    np.testing.assert_allclose(cloud.xyz, xyz, rtol=0, atol=1e-6)
    error_m = np.abs(local.astype(np.float64) + origin - xyz).max()
    assert error_m < 1e-3  # float32 has ~3e-5 m spacing at 500 m; at 1e7 m it would be 1 m
    assert np.abs(xyz.astype(np.float32).astype(np.float64) - xyz).max() > 0.1  # why the origin


# ---------------------------------------------------------------- bad input files

def _write_points(path: Path, n: int, point_format: int = 3) -> Path:
    header = laspy.LasHeader(point_format=point_format, version="1.2")
    las = laspy.LasData(header)
    if n:
        xyz = np.random.default_rng(3).uniform(0, 100, (n, 3))
        las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(path)
    return path


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match=r"nope\.laz: no such file"):
        las_io.read(tmp_path / "nope.laz")


def test_folder_is_not_a_file(tmp_path):
    with pytest.raises(InputError, match="is a folder"):
        las_io.read(tmp_path)


def test_not_a_las_file(tmp_path):
    path = tmp_path / "notes.laz"
    path.write_text("x y z\n1 2 3\n")
    with pytest.raises(InputError, match=r"notes\.laz: not a LAS/LAZ file"):
        las_io.read(path)


def test_header_only_stub_is_rejected(tmp_path):
    path = tmp_path / "stub.las"
    path.write_bytes(b"LASF\x00\x00")
    with pytest.raises(InputError, match=r"stub\.las: not a valid LAS/LAZ header"):
        las_io.read(path)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_zero_points(suffix, tmp_path):
    path = _write_points(tmp_path / f"empty{suffix}", 0)
    with pytest.raises(InputError, match=rf"empty\{suffix}: the file holds no points"):
        las_io.read(path)


def test_truncated_laz(tmp_path):
    full = _write_points(tmp_path / "full.laz", 5000).read_bytes()
    path = tmp_path / "cut.laz"
    path.write_bytes(full[: len(full) * 2 // 3])
    with pytest.raises(InputError, match=r"cut\.laz: truncated or corrupt LAZ"):
        las_io.read(path)


@pytest.mark.parametrize("cut_bytes,message", [
    (34 * 10, "truncated LAS file: header says 500 points, the file holds 490"),  # whole records
    (100, "truncated LAS file: header says 500 points, the file holds 497"),     # mid-record
])
def test_truncated_las(tmp_path, cut_bytes, message):
    full = _write_points(tmp_path / "full.las", 500).read_bytes()  # format 3: 34-byte records
    path = tmp_path / "cut.las"
    path.write_bytes(full[:-cut_bytes])
    with pytest.raises(InputError, match=rf"cut\.las: {message}"):
        las_io.read(path)


# ---------------------------------------------------------------- outputs

@pytest.fixture
def small_cloud(tmp_path) -> Cloud:
    return las_io.read(_write_points(tmp_path / "in.laz", 50))


def test_refuses_to_overwrite_the_input_without_force(small_cloud):
    before = small_cloud.path.read_bytes()
    with pytest.raises(InputError, match=r"in\.laz: is an input file; pass --force"):
        las_io.write(small_cloud, small_cloud.path)
    assert small_cloud.path.read_bytes() == before
    other = small_cloud.path.parent / "other.laz"
    other.write_bytes(b"")
    with pytest.raises(InputError, match="is an input file"):
        las_io.write(small_cloud, other, input_paths=[other])
    las_io.write(small_cloud, small_cloud.path, force=True)
    assert las_io.read(small_cloud.path).n_points == 50


def test_refuses_input_reached_through_a_symlink(small_cloud):
    link = small_cloud.path.parent / "link.laz"
    link.symlink_to(small_cloud.path)
    with pytest.raises(InputError, match="is an input file"):
        las_io.write(small_cloud, link)


@pytest.mark.parametrize("target,message", [
    ("missing_folder/out.laz", "output folder .* does not exist"),
    ("a_file.txt/out.laz", "is not a folder"),
    ("out.txt", r"output must end in \.las or \.laz"),
    ("a_folder.laz", "is a folder"),
])
def test_bad_output_paths(small_cloud, tmp_path, target, message):
    (tmp_path / "a_file.txt").write_text("not a folder")
    (tmp_path / "a_folder.laz").mkdir()
    before = sorted(os.listdir(tmp_path))
    with pytest.raises(InputError, match=message):
        las_io.write(small_cloud, tmp_path / target)
    assert sorted(os.listdir(tmp_path)) == before


def test_unwritable_output_folder(small_cloud, tmp_path, monkeypatch):
    # Tests may run as root, where chmod does not stop writes: fake the permission answer.
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == tmp_path else real_access(p, mode, **kw))
    with pytest.raises(InputError, match="is not writable"):
        las_io.write(small_cloud, tmp_path / "out.laz")


def test_failed_write_leaves_no_file(small_cloud, tmp_path, monkeypatch):
    before = sorted(os.listdir(tmp_path))

    def broken_write(self, points):
        self.dest.write(b"LASF partial")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(laspy.LasWriter, "write_points", broken_write)
    with pytest.raises(InputError, match=r"out\.laz: cannot write \(No space left on device\)"):
        las_io.write(small_cloud, tmp_path / "out.laz")
    assert sorted(os.listdir(tmp_path)) == before


def test_atomic_output_replaces_only_on_success(tmp_path):
    target = tmp_path / "dtm.tif"
    target.write_bytes(b"old")
    with pytest.raises(RuntimeError):
        with las_io.atomic_output(target) as tmp:
            assert tmp.parent == tmp_path and tmp.name.startswith(".dtm.tif.gfjax-tmp-")
            assert tmp.suffix.lower() not in (".las", ".laz", ".tif", ".tiff")   # never an input
            tmp.write_bytes(b"half")
            raise RuntimeError("writer crashed")
    assert target.read_bytes() == b"old" and sorted(os.listdir(tmp_path)) == ["dtm.tif"]
    with las_io.atomic_output(target) as tmp:
        tmp.write_bytes(b"new")
    assert target.read_bytes() == b"new" and sorted(os.listdir(tmp_path)) == ["dtm.tif"]
    assert (target.stat().st_mode & 0o777) == (0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# ---------------------------------------------------------------- several inputs

def test_expand_inputs_folders_globs_and_duplicates(tmp_path):
    for name in ("b.laz", "a.las", "c.LAZ", "notes.txt"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "d.laz").write_bytes(b"")
    folder = las_io.expand_inputs([tmp_path])
    assert [p.name for p in folder] == ["a.las", "b.laz", "c.LAZ"]
    globbed = las_io.expand_inputs([str(tmp_path / "*.la?"), str(tmp_path / "b.laz"), tmp_path / "sub"])
    assert [p.name for p in globbed] == ["a.las", "b.laz", "d.laz"]
    recursive = las_io.expand_inputs([str(tmp_path / "**" / "*.laz")])
    assert [p.name for p in recursive] == ["b.laz", "d.laz"]


@pytest.mark.parametrize("pattern,message", [
    ("nope.laz", "nope.laz: no such file or folder"),
    ("*.nothing", r"\*.nothing: no .las/.laz file matches"),
    (".", "folder holds no .las/.laz files"),
])
def test_expand_inputs_errors(tmp_path, monkeypatch, pattern, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(InputError, match=message):
        las_io.expand_inputs([pattern])
    with pytest.raises(InputError, match="no input files"):
        las_io.expand_inputs([])
