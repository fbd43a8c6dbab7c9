"""Catalogue: bad LAS/LAZ header values -> exit 2, one line naming the file and the field.

Every file is a valid small LAS/LAZ written by laspy, then one header field is patched. Each
case checks the exit code, the one error line (no traceback), and that no output is left.
"""
from __future__ import annotations

import os
import time

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli  # noqa: F401
from reliability_files import (
    HEADER_SIZE,
    MAX_X,
    NUMBER_OF_EVLRS,
    NUMBER_OF_VLRS,
    OFFSET,
    OFFSET_TO_POINTS,
    POINT_FORMAT,
    RECORD_LENGTH,
    SCALE,
    START_OF_FIRST_EVLR,
    VERSION_MINOR,
    patch,
    read_field,
    set_point_count,
    write_las,
)

from gfjax.errors import InputError
from gfjax.io import las as las_io


def _exits_2(capsys, path, *fragments):
    """`gfjax filter path` exits 2 in under 10 s with one line naming `path` and `fragments`."""
    folder = path.parent
    before = sorted(os.listdir(folder))
    start = time.perf_counter()
    code, out, err = run_cli(capsys, "filter", path, "-o", folder / "out.laz", "--method", "fake")
    assert time.perf_counter() - start < 10
    assert code == 2, (out, err)
    line = error_line(err)
    assert str(path) in line, line
    for fragment in fragments:
        assert fragment in line, line
    # One line; a file of this catalogue has no CRS, which filter may say first in a warning.
    assert [e for e in err.splitlines() if not e.startswith("gfjax: warning:")] == [line], err
    assert sorted(os.listdir(folder)) == before
    return line


@pytest.fixture
def las14(tmp_path):
    return write_las(tmp_path / "tile.las", version="1.4", point_format=6)


@pytest.fixture
def las12(tmp_path):
    return write_las(tmp_path / "tile.las", version="1.2", point_format=3)


@pytest.fixture
def laz14(tmp_path):
    return write_las(tmp_path / "tile.laz", version="1.4", point_format=6)


def test_absurd_point_count_in_las_exits_2_at_once(capsys, fake_methods, las14):
    set_point_count(las14, 10**15)
    _exits_2(capsys, las14, "header says 1000000000000000 points", "holds 300")


def test_absurd_point_count_in_laz_exits_2_at_once(capsys, fake_methods, laz14):
    set_point_count(laz14, 10**15)
    _exits_2(capsys, laz14, "header says 1000000000000000 points")


def test_absurd_vlr_count_exits_2_at_once(capsys, fake_methods, las14):
    patch(las14, NUMBER_OF_VLRS, 2**32 - 1)
    _exits_2(capsys, las14, "number of VLRs 4294967295")


def test_vlr_longer_than_the_space_before_points_exits_2(capsys, fake_methods, tmp_path):
    path = write_las(tmp_path / "tile.las")
    las = laspy.read(path)
    las.header.vlrs.append(laspy.VLR(user_id="gfjax_test", record_id=1, record_data=b"x" * 100))
    las.write(path)
    header_size = read_field(path, HEADER_SIZE)
    patch(path, (header_size + 20, "<H"), 60000)  # the record length of the first VLR
    _exits_2(capsys, path, "VLR 1 of 1 (record length 60000) runs past the offset to point data")


def test_absurd_evlr_count_exits_2_at_once(capsys, fake_methods, tmp_path):
    path = write_las(tmp_path / "tile.las", evlr=True)
    patch(path, NUMBER_OF_EVLRS, 2**32 - 1)
    _exits_2(capsys, path, "number of EVLRs 4294967295")


def test_evlr_start_past_end_of_file_exits_2(capsys, fake_methods, tmp_path):
    path = write_las(tmp_path / "tile.las", evlr=True)
    patch(path, START_OF_FIRST_EVLR, 2**60)
    _exits_2(capsys, path, "start of first EVLR 1152921504606846976 lies outside")


def test_evlr_record_length_past_end_of_file_exits_2(capsys, fake_methods, tmp_path):
    path = write_las(tmp_path / "tile.las", evlr=True)
    start = read_field(path, START_OF_FIRST_EVLR)
    patch(path, (start + 20, "<Q"), 2**62)
    _exits_2(capsys, path, "EVLR 1 of 1 (record length 4611686018427387904) runs past the end")


def test_record_length_shorter_than_point_format_exits_2(capsys, fake_methods, las14):
    patch(las14, RECORD_LENGTH, 12)
    _exits_2(capsys, las14, "point data record length 12 is less than the 30 bytes of point format 6")


def test_record_length_far_larger_than_data_exits_2(capsys, fake_methods, las14):
    patch(las14, RECORD_LENGTH, 65535)
    _exits_2(capsys, las14, "header says 300 points, the file holds 0")


def test_offset_to_point_data_past_end_of_file_exits_2(capsys, fake_methods, las14):
    patch(las14, OFFSET_TO_POINTS, 2**32 - 1)
    _exits_2(capsys, las14, "offset to point data 4294967295 lies past the end of the file")


def test_header_size_larger_than_offset_to_point_data_exits_2(capsys, fake_methods, las14):
    patch(las14, HEADER_SIZE, 65535)
    _exits_2(capsys, las14, "header size 65535 is larger than the offset to point data")


def test_header_size_smaller_than_the_version_needs_exits_2(capsys, fake_methods, las14):
    patch(las14, HEADER_SIZE, 227)
    _exits_2(capsys, las14, "header size 227 is less than the 375 bytes of a LAS 1.4 header")


def test_truncated_header_exits_2(capsys, fake_methods, las14):
    las14.write_bytes(las14.read_bytes()[:300])
    _exits_2(capsys, las14, "not a valid LAS/LAZ header (truncated: the file has 300 bytes")


@pytest.mark.parametrize("minor", [5, 9, 255])
def test_unsupported_las_version_exits_2(capsys, fake_methods, las14, minor):
    patch(las14, VERSION_MINOR, minor)
    _exits_2(capsys, las14, f"LAS version 1.{minor} is not supported")


def test_las_1_0_with_a_later_point_format_exits_2(capsys, fake_methods, las14):
    patch(las14, VERSION_MINOR, 0)
    _exits_2(capsys, las14, "point data format 6 is not part of LAS 1.0 (formats 0 to 1)")


def test_las_major_version_2_exits_2(capsys, fake_methods, las14):
    patch(las14, (24, "<B"), 2)
    _exits_2(capsys, las14, "LAS version 2.4 is not supported")


@pytest.mark.parametrize("point_format", [11, 63])
def test_unsupported_point_format_exits_2(capsys, fake_methods, las14, point_format):
    patch(las14, POINT_FORMAT, point_format)
    _exits_2(capsys, las14, f"point data format {point_format} is not supported")


@pytest.mark.parametrize("point_format", [4, 6])
def test_point_format_outside_its_las_version_exits_2(capsys, fake_methods, las12, point_format):
    patch(las12, POINT_FORMAT, point_format)
    _exits_2(capsys, las12, f"point data format {point_format} is not part of LAS 1.2 (formats 0 to 3)")


@pytest.mark.parametrize("value", [0.0, float("nan"), float("inf"), -float("inf")], ids=["zero", "nan", "inf", "-inf"])
def test_bad_scale_factor_exits_2(capsys, fake_methods, las14, value):
    patch(las14, SCALE["y"], value)
    _exits_2(capsys, las14, f"y scale factor is {value!r}")


@pytest.mark.parametrize("value", [1e306, 1e3], ids=["1e306", "1e3"])
def test_a_scale_factor_that_lets_coordinates_overflow_exits_2(capsys, fake_methods, las14, value):
    patch(las14, SCALE["x"], value)
    _exits_2(capsys, las14, f"x scale factor {value:g} with offset 500000 lets coordinates exceed 1e+12 units")


def test_an_offset_beyond_any_survey_exits_2(capsys, fake_methods, las14):
    patch(las14, OFFSET["y"], 5e12)
    _exits_2(capsys, las14, "y scale factor 0.01 with offset 5e+12 lets coordinates exceed 1e+12 units")


@pytest.mark.parametrize("value", [float("nan"), float("inf")], ids=["nan", "inf"])
def test_bad_offset_exits_2(capsys, fake_methods, las14, value):
    patch(las14, OFFSET["z"], value)
    _exits_2(capsys, las14, f"z offset is {value!r}")


def test_nan_extent_in_header_exits_2(capsys, fake_methods, las14):
    patch(las14, MAX_X, float("nan"))
    _exits_2(capsys, las14, "max x in the header is nan")


@pytest.mark.parametrize("limit", [2**31 - 1, -(2**31)], ids=["max", "min"])
def test_coordinates_at_the_int32_limit_exit_2(capsys, fake_methods, tmp_path, limit):
    path = write_las(tmp_path / "tile.las")
    las = laspy.read(path)
    x = np.asarray(las.X).copy()
    x[7] = limit
    las.X = x
    las.write(path)
    _exits_2(capsys, path, f"stored X integers reach the int32 limit {limit}")


def test_laz_chunk_table_offset_past_end_exits_2(capsys, fake_methods, laz14):
    patch(laz14, (read_field(laz14, OFFSET_TO_POINTS), "<q"), 2**40)
    _exits_2(capsys, laz14, "chunk table offset 1099511627776 lies outside the file")


def test_laz_without_laszip_vlr_exits_2(capsys, fake_methods, laz14):
    patch(laz14, NUMBER_OF_VLRS, 0)  # the LASzip VLR is no longer read
    _exits_2(capsys, laz14, "compressed points (LAZ) but no LASzip VLR")


def test_laz_absurd_chunk_count_exits_2(capsys, fake_methods, laz14):
    data = laz14.read_bytes()
    table_at = int.from_bytes(data[read_field(laz14, OFFSET_TO_POINTS):][:8], "little")
    patch(laz14, (table_at + 4, "<I"), 2**32 - 1)
    _exits_2(capsys, laz14, "chunk table lists 4294967295 chunks")


def test_header_checks_run_before_laspy_reads(tmp_path, monkeypatch):
    """laspy never sees a header that fails a check (it would loop over 4 billion VLRs)."""
    path = patch(write_las(tmp_path / "tile.las"), NUMBER_OF_VLRS, 2**32 - 1)
    monkeypatch.setattr(laspy, "open", lambda *a, **k: pytest.fail("laspy.open called"))
    with pytest.raises(InputError, match="number of VLRs"):
        las_io.read(path)
    with pytest.raises(InputError, match="number of VLRs"):
        las_io.read_header(path)


@pytest.mark.parametrize("suffix", [".las", ".laz"])
@pytest.mark.parametrize("version,point_format", [("1.2", 0), ("1.2", 3), ("1.3", 5), ("1.4", 6), ("1.4", 8),
                                                  ("1.4", 10)])
def test_valid_files_pass_every_check(tmp_path, suffix, version, point_format):
    path = write_las(tmp_path / f"tile{suffix}", version=version, point_format=point_format, n=1000)
    assert las_io.read(path).n_points == 1000


def test_non_ascii_vlr_description_is_written_back_unchanged(capsys, fake_methods, tmp_path):
    """laspy reads undecodable VLR text as bytes and refuses, by default, to write it back."""
    path = write_las(tmp_path / "tile.las")
    las = laspy.read(path)
    las.header.vlrs.append(laspy.VLR(user_id="gfjax_test", record_id=1, record_data=b"x"))
    las.write(path)
    data = bytearray(path.read_bytes())
    at = data.index(b"gfjax_test") - 2 + 22  # the VLR's description
    data[at:at + 4] = b"\xe9t\xe9\xa8"
    path.write_bytes(bytes(data))
    code, _, err = run_cli(capsys, "filter", path, "-o", tmp_path / "out.laz", "--method", "fake")
    assert code == 0, err
    vlrs = laspy.read(tmp_path / "out.laz").header.vlrs
    assert any(isinstance(v.description, bytes) and v.description.startswith(b"\xe9t\xe9\xa8") for v in vlrs)


def test_laz_layer_sizes_past_the_chunk_exit_2_at_once(capsys, fake_methods, laz14):
    """A garbage layer size made lazrs spend seconds per try; it is checked before lazrs runs."""
    start = read_field(laz14, OFFSET_TO_POINTS) + 8
    patch(laz14, (start + 30 + 4, "<I"), 2**31)  # the first layer of chunk 1 (format 6: 30-byte raw point)
    _exits_2(capsys, laz14, "the layers of chunk 1 of 1 take")


def test_laz_chunk_size_far_beyond_the_point_count_exits_2_at_once(capsys, fake_methods, laz14):
    """lazrs allocates a whole chunk per chunk: 321 million points of 30 bytes took 50 s."""
    body = laz14.read_bytes().index(b"laszip encoded") - 2 + 54  # the LASzip VLR's record
    at = body + 12                                                # its chunk size
    assert read_field(laz14, (at, "<I")) == 50_000
    patch(laz14, (at, "<I"), 321_367_179)
    _exits_2(capsys, laz14, "LASzip chunk size 321367179 is larger than the 300 points")
