"""Multi-file jobs: everything checked before the first file, a summary when a file fails,
`--keep-going`, and outputs already completed kept intact. Every file holds the same scene,
so the runs filter them `--independent`ly (a survey refuses the same tile twice)."""
from __future__ import annotations

import os
import shutil
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from cli_helpers import SCENE_CLASSES, error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401
from job_helpers import picky_method  # noqa: F401


@pytest.fixture
def folders(tmp_path) -> tuple[Path, Path]:
    source, out = tmp_path / "in", tmp_path / "out"
    source.mkdir()
    out.mkdir()
    return source, out


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def _gfjax_error_lines(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("gfjax:")]


def test_unreadable_later_input_fails_before_the_first_file_is_filtered(folders, capsys, fake_methods):
    source, out = folders
    write_scene(source / "a.las")
    (source / "b.las").write_bytes(b"LASF" + b"\0" * 50)          # signature, then a broken header
    code, _, err = run_cli(capsys, "filter", source / "a.las", source / "b.las", "-o", out, "--method", "fake", "--independent")
    assert code == 2
    assert "b.las: not a valid LAS/LAZ header" in error_line(err)
    assert fake_methods["fake"].calls == [] and _names(out) == []


def test_degree_crs_of_a_later_input_fails_before_the_first_file_is_filtered(folders, capsys, fake_methods):
    source, out = folders
    write_scene(source / "a.las")
    write_scene(source / "b.las", crs=pyproj.CRS.from_epsg(4326))
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "fake", "--independent")
    assert code == 2
    assert "b.las" in error_line(err) and "degree" in error_line(err)
    assert fake_methods["fake"].calls == [] and _names(out) == []


def test_output_equal_to_an_input_is_refused_before_filtering(folders, capsys, fake_methods):
    source, _ = folders
    write_scene(source / "a.las")
    write_scene(source / "b.las")
    code, _, err = run_cli(capsys, "filter", source / "a.las", source / "b.las", "-o", source, "--method", "fake", "--independent")
    assert code == 2
    assert "a.las: is an input file; pass --force" in error_line(err)
    assert fake_methods["fake"].calls == [] and _names(source) == ["a.las", "b.las"]


def test_unwritable_output_folder_is_refused_before_filtering(folders, capsys, fake_methods, monkeypatch):
    source, out = folders
    write_scene(source / "a.las")
    write_scene(source / "b.las")
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == out else real_access(p, mode, **kw))
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "fake", "--independent")
    assert code == 2 and "is not writable" in error_line(err)
    assert fake_methods["fake"].calls == [] and _names(out) == []


def test_outputs_larger_than_the_free_space_are_refused_before_filtering(folders, capsys, fake_methods, monkeypatch):
    source, out = folders
    write_scene(source / "a.las")
    write_scene(source / "b.las")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(10**9, 10**9 - 100, 100))
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "fake", "--independent")
    assert code == 2
    line = error_line(err)
    assert f"{out}: the outputs need about" in line and "only 100 bytes free" in line
    assert " KiB," in line or " MiB," in line                        # sizes in a unit that shows them, not 0.00 GiB
    assert fake_methods["fake"].calls == [] and _names(out) == []


def test_byte_sizes_take_the_unit_that_shows_them():
    from gfjax.limits import byte_size

    assert [byte_size(n) for n in (100, 3 * 2**10, 2.5 * 2**20, 3 * 2**30)] == \
        ["100 bytes", "3.00 KiB", "2.50 MiB", "3.00 GiB"]


def test_a_file_failing_during_the_run_keeps_completed_outputs_and_prints_a_summary(folders, capsys, picky_method):
    source, out = folders
    for name in ("a.las", "b_bad.las", "c.las"):
        write_scene(source / name)
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "picky", "--independent")
    assert code == 2
    lines = _gfjax_error_lines(err)
    assert lines[0] == f"gfjax: error: {source / 'b_bad.las'}: this file fails while it is filtered"
    assert lines[1].startswith(f"gfjax: 1 of 3 files done; failed: {source / 'b_bad.las'}; "
                               f"not started: {source / 'c.las'}")
    assert "--keep-going" in lines[1] and len(lines) == 2 and "Traceback" not in err
    assert _names(out) == ["a.las"]                                   # no partial or temporary file
    np.testing.assert_array_equal(laspy.read(out / "a.las").intensity, laspy.read(source / "a.las").intensity)
    assert len(laspy.read(out / "a.las").points) == len(SCENE_CLASSES)


def test_keep_going_filters_the_other_files_and_still_exits_2(folders, capsys, picky_method):
    source, out = folders
    for name in ("a.las", "b_bad.las", "c.las"):
        write_scene(source / name)
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "picky", "--independent", "--keep-going")
    assert code == 2
    lines = _gfjax_error_lines(err)
    assert lines == [f"gfjax: error: {source / 'b_bad.las'}: this file fails while it is filtered",
                     f"gfjax: 2 of 3 files done; failed: {source / 'b_bad.las'}"]
    assert _names(out) == ["a.las", "c.las"]


def test_keep_going_after_an_internal_error_exits_1_at_the_end(folders, capsys, picky_method):
    source, out = folders
    for name in ("a.las", "b_bug.las", "c.las"):
        write_scene(source / name)
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "picky", "--independent", "--keep-going")
    assert code == 1
    lines = _gfjax_error_lines(err)
    assert lines == [f"gfjax: internal error: {source / 'b_bug.las'}: RuntimeError: fake bug",
                     f"gfjax: 2 of 3 files done; failed: {source / 'b_bug.las'}"]
    assert _names(out) == ["a.las", "c.las"] and "Traceback" not in err


def test_internal_error_without_keep_going_stops_with_a_summary_and_exit_1(folders, capsys, picky_method):
    source, out = folders
    for name in ("a.las", "b_bug.las", "c.las"):
        write_scene(source / name)
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "picky", "--independent")
    assert code == 1
    lines = _gfjax_error_lines(err)
    assert lines[0].startswith(f"gfjax: 1 of 3 files done; failed: {source / 'b_bug.las'}; not started")
    assert lines[1].startswith("gfjax: internal error: RuntimeError: fake bug")
    assert _names(out) == ["a.las"]


def test_all_files_done_prints_no_summary_and_exits_0(folders, capsys, picky_method):
    source, out = folders
    for name in ("a.las", "b.las"):
        write_scene(source / name)
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "picky", "--independent")
    assert code == 0 and _gfjax_error_lines(err) == []
    assert _names(out) == ["a.las", "b.las"]


def test_single_file_failure_is_one_line_without_summary(folders, capsys, picky_method):
    source, out = folders
    write_scene(source / "b_bad.las")
    code, _, err = run_cli(capsys, "filter", source / "b_bad.las", "-o", out / "b.las", "--method", "picky")
    assert code == 2
    assert _gfjax_error_lines(err) == [f"gfjax: error: {source / 'b_bad.las'}: this file fails while it is filtered"]
    assert _names(out) == []
