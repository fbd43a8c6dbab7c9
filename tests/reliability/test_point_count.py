"""Catalogue: a header point count that disagrees with the data -> exit 2 naming both counts,
never a silent loss; `gfjax filter --trust-data` filters the points present and says so."""
from __future__ import annotations

import os

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli  # noqa: F401
from reliability_files import append_points, set_point_count, write_las

from gfjax.errors import InputError
from gfjax.io import las as las_io


def _exits_2(capsys, path, *fragments):
    folder = path.parent
    before = sorted(os.listdir(folder))
    code, out, err = run_cli(capsys, "filter", path, "-o", folder / "out.laz", "--method", "fake")
    assert code == 2, (out, err)
    line = error_line(err)
    assert str(path) in line
    for fragment in fragments:
        assert fragment in line, line
    assert sorted(os.listdir(folder)) == before


def _trusted(capsys, path, expected_n):
    """`--trust-data` writes every point present and says so on stderr, once."""
    out_path = path.parent / "out.las"
    code, out, err = run_cli(capsys, "filter", path, "-o", out_path, "--method", "fake", "--trust-data")
    assert code == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("gfjax: warning:") and "--trust-data" in line]
    assert len(warnings) == 1 and str(path) in warnings[0] and f"holds {expected_n:,}" in warnings[0], err
    written = laspy.read(out_path)
    assert len(written.points) == expected_n and written.header.point_count == expected_n
    return written


def test_header_point_count_smaller_than_las_data_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.las", n=300), 200)
    _exits_2(capsys, path, "header says 200 points, the LAS data holds 300", "--trust-data")


def test_points_appended_after_las_data_exit_2(capsys, fake_methods, tmp_path):
    path = append_points(write_las(tmp_path / "tile.las", n=300), 40)
    _exits_2(capsys, path, "header says 300 points, the LAS data holds 340")


def test_header_point_count_larger_than_file_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.las", n=300), 301)
    _exits_2(capsys, path, "truncated LAS file: header says 301 points, the file holds 300")


def test_header_point_count_zero_with_points_present_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.las", n=300), 0)
    _exits_2(capsys, path, "header says 0 points, the LAS data holds 300")


def test_legacy_count_of_las_1_2_smaller_than_data_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.las", n=300, version="1.2", point_format=3), 299)
    _exits_2(capsys, path, "header says 299 points, the LAS data holds 300")


@pytest.mark.parametrize("header_n", [1, 1100, 1199])
def test_header_point_count_smaller_than_laz_data_exits_2(capsys, fake_methods, tmp_path, header_n):
    path = set_point_count(write_las(tmp_path / "tile.laz", n=1200), header_n)
    _exits_2(capsys, path, f"header says {header_n} points, the LAZ data holds 1200")


def test_header_point_count_smaller_than_laz_data_of_several_chunks_exits_2(capsys, fake_methods, tmp_path):
    """52,119 points in two 50,000-point chunks, a header that says 51,119 (the silent loss
    reported against 0.1.0: both counts need two chunks, so only the last chunk tells)."""
    path = set_point_count(write_las(tmp_path / "tile.laz", n=52_119, version="1.2", point_format=3), 51_119)
    _exits_2(capsys, path, "header says 51119 points, the LAZ data holds 52119")


def test_header_point_count_larger_than_laz_data_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.laz", n=1200), 1300)
    _exits_2(capsys, path, "truncated LAZ file: header says 1300 points, the file holds 1200")


def test_laz_header_claiming_another_chunk_exits_2(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.laz", n=1200), 50_000 + 1200)
    _exits_2(capsys, path, "header says 51200 points", "1200")


def test_trust_data_filters_every_las_point_present(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las", n=300)
    intensity = np.asarray(laspy.read(source).intensity)
    written = _trusted(capsys, set_point_count(source, 200), 300)
    np.testing.assert_array_equal(np.asarray(written.intensity), intensity)


def test_trust_data_filters_appended_las_points(capsys, fake_methods, tmp_path):
    path = append_points(write_las(tmp_path / "tile.las", n=300), 40)
    _trusted(capsys, path, 340)


def test_trust_data_filters_what_a_truncated_las_holds(capsys, fake_methods, tmp_path):
    path = write_las(tmp_path / "tile.las", n=300)
    path.write_bytes(path.read_bytes()[:-30 * 10])
    _trusted(capsys, path, 290)


def test_trust_data_filters_every_laz_point_present(capsys, fake_methods, tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.laz", n=52_119, version="1.2", point_format=3), 51_119)
    _trusted(capsys, path, 52_119)


def test_trust_data_keeps_every_attribute(tmp_path):
    source = write_las(tmp_path / "tile.las", n=300)
    original = laspy.read(source)
    set_point_count(source, 250)
    cloud = las_io.read(source, trust_data=True)
    assert cloud.n_points == 300
    for name in original.point_format.dimension_names:
        np.testing.assert_array_equal(np.asarray(cloud.las[name]), np.asarray(original[name]), err_msg=name)


def test_matching_counts_need_no_trust(tmp_path):
    path = write_las(tmp_path / "tile.laz", n=52_119, version="1.2", point_format=3)
    assert las_io.read(path).n_points == 52_119
    assert las_io.read(path, trust_data=True).n_points == 52_119


def test_read_without_trust_names_both_counts(tmp_path):
    path = set_point_count(write_las(tmp_path / "tile.las", n=300), 200)
    with pytest.raises(InputError, match=r"tile\.las: header says 200 points, the LAS data holds 300"):
        las_io.read(path)
    with pytest.raises(InputError, match=r"tile\.las: header says 200 points"):
        las_io.read_header(path)


def test_layered_laz_chunk_claiming_more_points_than_its_bytes_exits_2(tmp_path):
    """--trust-data must not allocate what a corrupt chunk claims (4 billion points)."""
    from reliability_files import OFFSET_TO_POINTS, patch, read_field

    path = write_las(tmp_path / "tile.laz", n=300)
    patch(path, (read_field(path, OFFSET_TO_POINTS) + 8 + 30, "<I"), 2**32 - 1)  # chunk 1's point count
    with pytest.raises(InputError, match="chunk 1 of 1 says it holds 4294967295 points"):
        las_io.read(path, trust_data=True)
