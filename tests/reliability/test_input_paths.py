"""Catalogue: inputs and outputs that are not plain file names -> exit 2 with one line, never a
hang: FIFOs, devices, folders, names the system refuses as too long, empty arguments."""
from __future__ import annotations

import os
import stat

import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli  # noqa: F401
from reliability_files import run_gfjax, write_las

from gfjax.errors import InputError
from gfjax.io import atomic, las_layout
from gfjax.io import las as las_io

NAME_MAX = os.pathconf("/", "PC_NAME_MAX")


def _exits_2(capsys, folder, argv, *fragments):
    before = sorted(os.listdir(folder))
    code, out, err = run_cli(capsys, *argv)
    assert code == 2, (out, err)
    line = error_line(err)
    for fragment in fragments:
        assert fragment in line, line
    assert sorted(os.listdir(folder)) == before
    return line


def _subprocess_exits_2(done, *fragments):
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    for fragment in fragments:
        assert fragment in done.stderr, done.stderr


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "pipe.laz"
    os.mkfifo(path)
    return path


def test_fifo_input_exits_2_without_blocking(fifo, tmp_path):
    """Opening a FIFO for reading blocks until a writer comes: the file type is checked first."""
    _subprocess_exits_2(run_gfjax("info", fifo, timeout=60), f"{fifo}: is a FIFO (named pipe), not a LAS/LAZ file")
    _subprocess_exits_2(run_gfjax("filter", fifo, "-o", tmp_path / "out.laz", timeout=60), "is a FIFO")
    assert not (tmp_path / "out.laz").exists()


def test_fifo_given_to_read_raises_input_error(fifo):
    with pytest.raises(InputError, match="is a FIFO"):
        las_io.read(fifo)


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_character_device_input_exits_2(capsys, fake_methods, tmp_path):
    _exits_2(capsys, tmp_path, ["filter", "/dev/zero", "-o", tmp_path / "out.laz", "--method", "fake"],
             "/dev/zero: is a character device, not a LAS/LAZ file")


def test_block_device_input_exits_2(tmp_path, monkeypatch):
    path = write_las(tmp_path / "disk.las")
    real_stat = os.stat
    block = os.stat_result((stat.S_IFBLK | 0o660, *real_stat(path)[1:]))
    monkeypatch.setattr(las_layout.os, "stat", lambda p, *a, **k: block if os.fspath(p) == str(path) else real_stat(p, *a, **k))
    with pytest.raises(InputError, match=r"disk\.las: is a block device, not a LAS/LAZ file"):
        las_io.read(path)


def test_folder_named_like_a_las_file_exits_2(capsys, fake_methods, tmp_path):
    folder = tmp_path / "tile.laz"
    folder.mkdir()
    _exits_2(capsys, tmp_path, ["filter", folder, "-o", tmp_path / "out.laz", "--method", "fake"],
             "tile.laz: folder holds no .las/.laz files")
    with pytest.raises(InputError, match=r"tile\.laz: is a folder"):
        las_io.read(folder)


def test_input_name_too_long_exits_2(capsys, fake_methods, tmp_path):
    name = tmp_path / ("x" * (NAME_MAX + 1) + ".laz")
    _exits_2(capsys, tmp_path, ["filter", name, "-o", tmp_path / "out.laz", "--method", "fake"],
             "cannot open (File name too long)")


def test_input_name_too_long_given_to_read_raises_input_error(tmp_path):
    with pytest.raises(InputError, match="File name too long"):
        las_io.read(tmp_path / ("x" * (NAME_MAX + 1) + ".laz"))


def test_output_name_too_long_exits_2(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las")
    _exits_2(capsys, tmp_path, ["filter", source, "-o", tmp_path / ("y" * (NAME_MAX + 1) + ".laz"),
                                "--method", "fake"], "cannot write (File name too long)")


def test_dtm_name_too_long_exits_2(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las")
    _exits_2(capsys, tmp_path, ["filter", source, "-o", tmp_path / "out.laz", "--method", "fake",
                                "--dtm", tmp_path / ("d" * (NAME_MAX + 1) + ".tif")], "File name too long")


def test_empty_input_argument_exits_2(capsys, fake_methods, tmp_path):
    _exits_2(capsys, tmp_path, ["filter", "", "-o", tmp_path / "out.laz", "--method", "fake"],
             "IN: empty argument ''")


def test_empty_input_argument_beside_a_good_one_exits_2(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las")
    _exits_2(capsys, tmp_path, ["filter", source, "", "-o", tmp_path, "--method", "fake"], "IN: empty argument ''")


def test_empty_output_argument_exits_2(capsys, fake_methods, tmp_path, monkeypatch):
    source = write_las(tmp_path / "tile.las")
    monkeypatch.chdir(tmp_path)  # '' must not mean the current folder
    _exits_2(capsys, tmp_path, ["filter", source, "-o", "", "--method", "fake"], "-o: empty argument ''")


def test_empty_dtm_argument_exits_2(capsys, fake_methods, tmp_path, monkeypatch):
    source = write_las(tmp_path / "tile.las")
    monkeypatch.chdir(tmp_path)
    _exits_2(capsys, tmp_path, ["filter", source, "-o", tmp_path / "out.laz", "--method", "fake", "--dtm", ""],
             "--dtm: empty argument ''")


def test_empty_params_argument_exits_2(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las")
    _exits_2(capsys, tmp_path, ["filter", source, "-o", tmp_path / "out.laz", "--method", "fake", "--params", ""],
             "--params: empty argument ''")


def test_empty_name_given_to_check_output_raises_input_error():
    with pytest.raises(InputError, match="empty output name"):
        atomic.check_output("")


def test_info_of_an_empty_argument_exits_2(capsys, tmp_path):
    _exits_2(capsys, tmp_path, ["info", ""], "empty argument ''")


def test_empty_set_value_exits_2(capsys, fake_methods, tmp_path):
    source = write_las(tmp_path / "tile.las")
    _exits_2(capsys, tmp_path, ["filter", source, "-o", tmp_path / "out.laz", "--method", "fake", "--set", ""],
             "--set: empty argument ''")


def test_empty_name_given_to_expand_inputs_raises_input_error():
    with pytest.raises(InputError, match="empty input name"):
        las_io.expand_inputs([""])
