"""`gfjax filter --dtm`: a DTM problem is found before the point cloud is written, or neither
file is written."""
from __future__ import annotations

import os
from pathlib import Path

import laspy
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401
from job_helpers import picky_method  # noqa: F401

from gfjax.errors import InputError


@pytest.fixture
def scene(tmp_path) -> Path:
    return write_scene(tmp_path / "in.las")


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def test_no_ground_points_writes_neither_the_cloud_nor_the_dtm(tmp_path, capsys, picky_method):
    source = write_scene(tmp_path / "noground.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--method", "picky")
    assert code == 2
    assert "noground.las: no ground points" in error_line(err)
    assert _names(tmp_path) == ["noground.las"]


def test_dtm_cell_absurd_for_the_extent_fails_before_filtering(scene, tmp_path, capsys, fake_methods, monkeypatch):
    monkeypatch.setenv("GFJAX_MEMORY_BUDGET_GB", "0.5")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--cell", "0.0005", "--method", "fake")
    assert code == 2
    line = error_line(err)
    assert f"{scene}: a DTM of" in line and "(extent / --cell) needs about" in line and "memory budget of 0.5 GiB" in line
    assert fake_methods["fake"].calls == [] and _names(tmp_path) == ["in.las"]


def test_dtm_cell_out_of_range_fails_before_reading(scene, tmp_path, capsys, fake_methods):
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--cell", "5000", "--method", "fake")
    assert code == 2
    assert error_line(err) == "gfjax: error: --cell: cell_m must be > 0 and <= 1000 m, got 5000.0"
    assert fake_methods["fake"].calls == [] and _names(tmp_path) == ["in.las"]


def test_dtm_write_failure_leaves_no_point_cloud(scene, tmp_path, capsys, fake_methods, monkeypatch):
    from gfjax.dtm import DTM

    def full_disk(self, path):
        raise InputError(f"{path}: cannot write (No space left on device)")

    monkeypatch.setattr(DTM, "to_geotiff", full_disk)
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--method", "fake")
    assert code == 2 and "dtm.tif: cannot write (No space left on device)" in error_line(err)
    assert _names(tmp_path) == ["in.las"]


def _fail_renames_to(monkeypatch, name: str) -> None:
    """`os.replace` and `os.link` (the exclusive move without `--force`) onto a path ending in
    `name` fail as on a full disk."""
    real_replace, real_link = os.replace, os.link

    def failing(real):
        def move(src, dst, **kwargs):
            if str(dst).endswith(name):
                raise OSError(28, "No space left on device")
            return real(src, dst, **kwargs)
        return move

    monkeypatch.setattr(os, "replace", failing(real_replace))
    monkeypatch.setattr(os, "link", failing(real_link))


def test_point_cloud_rename_failure_removes_the_new_dtm(scene, tmp_path, capsys, fake_methods, monkeypatch):
    _fail_renames_to(monkeypatch, "out.laz")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--method", "fake")
    assert code == 2 and "out.laz: cannot write" in error_line(err)
    assert _names(tmp_path) == ["in.las"]


def test_point_cloud_rename_failure_with_force_puts_the_earlier_dtm_back(scene, tmp_path, capsys, fake_methods,
                                                                         monkeypatch):
    out, dtm = tmp_path / "out.laz", tmp_path / "dtm.tif"
    code, _, _ = run_cli(capsys, "filter", scene, "-o", out, "--dtm", dtm, "--method", "fake")
    assert code == 0
    before = {path: path.read_bytes() for path in (out, dtm)}
    _fail_renames_to(monkeypatch, "out.laz")
    code, _, err = run_cli(capsys, "filter", scene, "-o", out, "--dtm", dtm, "--method", "fake", "--cell", "2",
                           "--force")
    assert code == 2 and "out.laz: cannot write" in error_line(err)
    assert _names(tmp_path) == ["dtm.tif", "in.las", "out.laz"]         # no temporary left
    assert {path: path.read_bytes() for path in (out, dtm)} == before     # the old pair, unchanged


def test_cloud_and_dtm_are_both_written_on_success(scene, tmp_path, capsys, fake_methods):
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--dtm", tmp_path / "dtm.tif",
                           "--method", "fake")
    assert code == 0, err
    assert _names(tmp_path) == ["dtm.tif", "in.las", "out.laz"]
    assert len(laspy.read(tmp_path / "out.laz").points) == len(laspy.read(scene).points)


def test_multi_file_dtm_failure_keeps_earlier_pairs_whole(tmp_path, capsys, picky_method):
    source, out = tmp_path / "in", tmp_path / "out"
    source.mkdir()
    out.mkdir()
    write_scene(source / "a.las")
    write_scene(source / "b_noground.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--dtm", out, "--method", "picky", "--independent", "--keep-going")
    assert code == 2
    assert "b_noground.las: no ground points" in err
    assert _names(out) == ["a.las", "a.tif"]
