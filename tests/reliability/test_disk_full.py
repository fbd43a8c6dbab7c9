"""Catalogue: a full disk (ENOSPC) while writing LAS or LAZ output -> exit 2 with one line
naming the output, and nothing left behind (no output, no temporary file).

The disk is filled by a file object whose `write` raises `OSError(ENOSPC)` once a byte budget is
spent, so laspy (LAS) and lazrs (LAZ, which calls `write` from Rust) meet it mid-file.
"""
from __future__ import annotations

import errno
import io
import os

import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli  # noqa: F401
from reliability_files import write_las

from gfjax.errors import InputError
from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud


class _FullDisk(io.FileIO):
    budget = 0

    def write(self, data) -> int:
        size = len(memoryview(data))
        if _FullDisk.budget < size:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        _FullDisk.budget -= size
        return super().write(data)


@pytest.fixture
def full_disk(monkeypatch):
    """The disk fills after `budget` bytes of each LAS/LAZ file gfjax writes."""
    def fake_open(path, mode="r", *args, **kwargs):
        assert "b" in mode
        return io.BufferedRandom(_FullDisk(path, "w+"))

    monkeypatch.setattr(las_io, "open", fake_open, raising=False)
    return _FullDisk


@pytest.mark.parametrize("budget", [0, 100, 3000])
@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_disk_full_while_writing_exits_2_and_leaves_nothing(capsys, fake_methods, tmp_path, full_disk, suffix, budget):
    source = write_las(tmp_path / "tile.las", n=5000)
    full_disk.budget = budget
    out = tmp_path / f"out{suffix}"
    before = sorted(os.listdir(tmp_path))
    code, _, err = run_cli(capsys, "filter", source, "-o", out, "--method", "fake")
    assert code == 2, err
    assert error_line(err) == f"gfjax: error: {out}: cannot write (No space left on device)"
    assert sorted(os.listdir(tmp_path)) == before


@pytest.mark.parametrize("suffix", [".las", ".laz"])
def test_disk_full_in_write_raises_input_error(tmp_path, full_disk, suffix):
    cloud = Cloud.from_xyz(np.random.default_rng(0).uniform(0, 100, (20_000, 3)))
    full_disk.budget = 10_000
    with pytest.raises(InputError, match="No space left on device"):
        las_io.write(cloud, tmp_path / f"out{suffix}")
    assert os.listdir(tmp_path) == []


def test_other_laz_write_errors_stay_internal_errors(tmp_path, monkeypatch):
    """Only an OSError from the file is bad input; lazrs failing by itself is a bug (exit 1)."""
    import laspy

    def broken(self, *args, **kwargs):
        raise RuntimeError("compressor bug")

    monkeypatch.setattr(laspy.LasWriter, "write_points", broken)
    cloud = Cloud.from_xyz(np.zeros((3, 3)))
    with pytest.raises(RuntimeError, match="compressor bug"):
        las_io.write(cloud, tmp_path / "out.laz")
    assert os.listdir(tmp_path) == []


def test_disk_full_while_saving_a_model_raises_input_error_and_leaves_nothing(tmp_path, monkeypatch):
    """`gfjax train` saves its model and its state after every epoch: a full disk there is
    bad input naming the file (exit 2), and no model or temporary is left."""
    import builtins

    from gfjax.sparsegf import checkpoint
    from gfjax.sparsegf.model import NET_PRESETS, init

    model = init(NET_PRESETS["tiny"], key=None)        # zero weights: a file of the same size, no draw to compile
    real_open = builtins.open

    def full_open(path, mode="r", *args, **kwargs):
        if "w" in mode:
            _FullDisk.budget = 1000
            return io.BufferedWriter(_FullDisk(path, "w"))
        return real_open(path, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", full_open)
    out = tmp_path / "model.eqx"
    with pytest.raises(InputError, match=f"^{out}: cannot write \\(No space left on device\\)$"):
        checkpoint.save(out, model)
    monkeypatch.undo()
    assert os.listdir(tmp_path) == []


def test_disk_full_while_writing_a_dtm_gives_one_line_naming_the_reason(tmp_path):
    """libtiff prints its complaints on the process's stderr from C; the command's one line says
    the first of them, and nothing else reaches the user. A file-size limit (SIGXFSZ ignored)
    makes every write past 20 KiB fail as a full disk would."""
    import subprocess
    import sys

    import matplotlib.font_manager  # noqa: F401 (its cache written now, not under the child's limit)

    from gfjax.data import demo_sample

    small_disk = ("import resource, runpy, signal, sys; signal.signal(signal.SIGXFSZ, signal.SIG_IGN); "
                  "resource.setrlimit(resource.RLIMIT_FSIZE, (20 * 1024, 20 * 1024)); "
                  "sys.argv[0] = 'gfjax'; runpy.run_module('gfjax.cli.main', run_name='__main__')")
    out = tmp_path / "dtm.tif"
    done = subprocess.run([sys.executable, "-c", small_disk, "dtm", str(demo_sample()), "-o", str(out)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line]
    assert lines == [f"gfjax: error: {out}: cannot write (_tiffWriteProc: File too large.)"], done.stderr
    assert os.listdir(tmp_path) == []
