"""Files without a usable CRS: read as metres, and said once per run on stderr."""
from __future__ import annotations

import laspy
import pytest
from cli_helpers import fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401
from laspy.vlrs.known import WktCoordinateSystemVlr


def _warnings(err: str) -> list[str]:
    assert "Traceback" not in err, err
    return [line for line in err.splitlines() if line.startswith("gfjax: warning:")]


def _blank_wkt_scene(path):
    """A scene whose only CRS record is a blank WKT, as in PDAL's test file warsaw_small.las."""
    write_scene(path, crs=None)
    las = laspy.read(path)
    las.header.vlrs.append(WktCoordinateSystemVlr(" \n"))
    las.write(path)
    return path


def test_filter_says_once_that_files_without_crs_are_taken_as_metres(tmp_path, capsys, fake_methods):
    (tmp_path / "out").mkdir()
    sources = [write_scene(tmp_path / name, crs=None) for name in ("a.las", "b.las", "c.las", "d.las")]
    code, _, err = run_cli(capsys, "filter", *sources, "-o", tmp_path / "out", "--method", "fake", "--independent")
    assert code == 0, err
    assert _warnings(err) == [f"gfjax: warning: {sources[0]}, {sources[1]}, {sources[2]} and 1 more files: no CRS; "
                              "coordinates taken as metres (pass --units m|ft|us-ft if they are not)"]


@pytest.mark.parametrize("crs_given", ["--units", "CRS"])
def test_no_warning_when_the_units_are_stated(tmp_path, capsys, fake_methods, crs_given):
    source = write_scene(tmp_path / "in.las", **({"crs": None} if crs_given == "--units" else {}))
    options = ["--units", "m"] if crs_given == "--units" else []
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.las", "--method", "fake", *options)
    assert code == 0 and _warnings(err) == [], err


@pytest.mark.parametrize("command", ["filter", "dtm", "eval --method", "eval --reference"])
def test_an_empty_crs_record_is_read_as_no_crs_and_said_once(tmp_path, capsys, fake_methods, command):
    source = _blank_wkt_scene(tmp_path / "w.las")
    argv = {"filter": ["filter", source, "-o", tmp_path / "out.las", "--method", "fake"],
            "dtm": ["dtm", source, "-o", tmp_path / "d.tif"],
            "eval --method": ["eval", source, "--method", "fake"],
            "eval --reference": ["eval", source, "--reference", source]}[command]
    code, _, err = run_cli(capsys, *argv)
    assert code == 0, err
    metres = "; coordinates taken as metres (pass --units m|ft|us-ft if they are not)"
    said = f"gfjax: warning: {source}: empty WKT CRS record, read as no CRS"
    assert _warnings(err) == [said + ("" if command == "eval --reference" else metres)]


def test_info_describes_a_file_whose_crs_record_is_empty(tmp_path, capsys):
    source = _blank_wkt_scene(tmp_path / "w.las")
    code, out, err = run_cli(capsys, "info", source)
    assert code == 0, err
    assert "CRS         none (empty WKT CRS record, read as no CRS)" in out
    assert "[no usable CRS in file: metres assumed]" in out
