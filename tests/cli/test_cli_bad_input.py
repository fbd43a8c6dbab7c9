"""Bad input: one-line message naming the file or option, exit 2, no output left."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
    """A good file, a text file, a truncated LAZ, a zero-point LAS, and a plain file."""
    good = write_scene(tmp_path / "good.laz")
    big = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    xyz = np.random.default_rng(0).uniform(0, 100, (5000, 3))
    big.x, big.y, big.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    big.write(tmp_path / "whole.laz")
    data = (tmp_path / "whole.laz").read_bytes()
    (tmp_path / "truncated.laz").write_bytes(data[: len(data) // 2])
    (tmp_path / "whole.laz").unlink()
    laspy.LasData(laspy.LasHeader(point_format=3, version="1.2")).write(tmp_path / "empty.las")
    (tmp_path / "text.laz").write_text("this is not a point cloud\n")
    (tmp_path / "plain_file").write_text("a file, not a folder\n")
    return {"good": good, "truncated": tmp_path / "truncated.laz", "empty": tmp_path / "empty.las",
            "text": tmp_path / "text.laz", "plain_file": tmp_path / "plain_file", "dir": tmp_path}


def _check(capsys, files, argv, message):
    """Exit 2, exactly one error line containing `message`, and no new file anywhere."""
    before = sorted(os.listdir(files["dir"]))
    code, out, err = run_cli(capsys, *argv)
    assert code == 2, (argv, out, err)
    assert message in error_line(err), err
    assert sorted(os.listdir(files["dir"])) == before


CASES = {
    "missing file": (["filter", "{dir}/nope.laz", "-o", "{dir}/out.laz", "--method", "fake"],
                     "nope.laz: no such file"),
    "not LAS/LAZ": (["filter", "{text}", "-o", "{dir}/out.laz", "--method", "fake"],
                    "text.laz: not a LAS/LAZ file"),
    "truncated LAZ": (["filter", "{truncated}", "-o", "{dir}/out.laz", "--method", "fake"],
                      "truncated.laz: truncated or corrupt LAZ data"),
    "zero points": (["filter", "{empty}", "-o", "{dir}/out.laz", "--method", "fake"],
                    "empty.las: the file holds no points"),
    "unknown --set key": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--set", "bogus=1"],
                          "--set: unknown key 'bogus' for method fake; known keys: cell_m, threshold_m"),
    "--set without =": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--set", "cell_m"],
                        "--set 'cell_m': expected KEY=VALUE"),
    "--set not a number": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--set", "cell_m=big"],
                           "--set cell_m=big: could not convert"),
    "negative --set cell": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--set", "cell_m=-1"],
                            "--set: cell_m must be > 0, got -1.0"),
    "negative params value": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake",
                               "--set", "threshold_m=-2"], "--set: threshold_m must be >= 0, got -2.0"),
    "negative --cell": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--dtm",
                         "{dir}/d.tif", "--cell", "-1"], "--cell: must be a positive number, got -1"),
    "zero --tile-size": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--tile-size", "0"],
                         "--tile-size: must be a positive number, got 0"),
    "unknown preset": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--preset", "x"],
                       "--preset: unknown preset 'x' for fake; choose from generous"),
    "bad --units": (["filter", "{good}", "-o", "{dir}/out.laz", "--method", "fake", "--units", "yd"],
                    "--units: invalid choice: 'yd'"),
    "output is the input": (["filter", "{good}", "-o", "{good}", "--method", "fake"],
                            "good.laz: is an input file; pass --force to overwrite it"),
    "output folder missing": (["filter", "{good}", "-o", "{dir}/no/such/out.laz", "--method", "fake"],
                              "does not exist"),
    "output under a file": (["filter", "{good}", "-o", "{plain_file}/out.laz", "--method", "fake"],
                            "plain_file is not a folder"),
    "output suffix": (["filter", "{good}", "-o", "{dir}/out.txt", "--method", "fake"],
                      r"out.txt: output must end in .las or .laz"),
    "missing -o": (["filter", "{good}", "--method", "fake"],
                   "gfjax filter: the following arguments are required: -o/--output"),
    "missing params file": (["filter", "{good}", "-o", "{dir}/out.laz", "--params", "{dir}/p.json"],
                            "--params {dir}/p.json: no such file"),
    "info missing file": (["info", "{dir}/nope.laz"], "nope.laz: no such file"),
    "info truncated LAZ": (["info", "{truncated}"], "truncated.laz: truncated or corrupt LAZ data"),
    "dtm zero points": (["dtm", "{empty}", "-o", "{dir}/d.tif"], "empty.las: the file holds no points"),
    "dtm negative cell": (["dtm", "{good}", "-o", "{dir}/d.tif", "--cell", "-0.5"],
                          "--cell: must be a positive number, got -0.5"),
    "dtm output is a LAS": (["dtm", "{good}", "-o", "{dir}/d.laz"], "output must end in .tif or .tiff"),
    "dtm output folder missing": (["dtm", "{good}", "-o", "{dir}/no/d.tif"], "does not exist"),
    "eval without reference or method": (["eval", "{good}"], "--reference or --method"),
    "eval reference of other points": (["eval", "{good}", "--reference", "{truncated}"],
                                       "truncated.laz: truncated or corrupt LAZ data"),
    "unknown command": (["nosuch"], "COMMAND: invalid choice: 'nosuch'"),
}


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_bad_input_exits_2_with_one_line(case, files, capsys, fake_methods):
    argv, message = CASES[case]
    fields = {k: str(v) for k, v in files.items()}
    _check(capsys, files, [a.format(**fields) for a in argv], message.format(**fields))


def test_unwritable_output_folder(files, capsys, fake_methods, monkeypatch):
    # Tests may run as root, where chmod does not stop writes: fake the permission answer.
    real_access = os.access
    folder = files["dir"]
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: False if Path(p) == folder else real_access(p, mode, **kw))
    _check(capsys, files, ["filter", str(files["good"]), "-o", str(folder / "out.laz"), "--method", "fake"],
           "is not writable")


def test_internal_error_exits_1_without_traceback(files, capsys, fake_methods, monkeypatch):
    argv = ["filter", str(files["good"]), "-o", str(files["dir"] / "out.laz"), "--method", "fake_crash"]
    before = sorted(os.listdir(files["dir"]))
    code, _, err = run_cli(capsys, *argv)
    assert code == 1
    assert err.strip().splitlines()[-1].startswith("gfjax: internal error: RuntimeError: fake method crashed")
    assert "Traceback" not in err
    code, _, err = run_cli(capsys, *argv, "--debug")
    assert code == 1 and "Traceback" in err
    monkeypatch.setenv("GFJAX_DEBUG", "1")
    code, _, err = run_cli(capsys, *argv)
    assert code == 1 and "Traceback" in err
    assert sorted(os.listdir(files["dir"])) == before


def test_force_overwrites_the_input(files, capsys, fake_methods):
    code, _, err = run_cli(capsys, "filter", files["good"], "-o", files["good"], "--method", "fake", "--force")
    assert code == 0, err
    assert laspy.read(files["good"]).classification[5] == 1  # z 9 m, was class 2


def _gfjax(*argv, env=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "gfjax.cli.main", *map(str, argv)], capture_output=True,
                          text=True, cwd=REPO, env={**os.environ, **(env or {})}, timeout=120)


def test_subprocess_exit_codes_and_messages(files):
    done = _gfjax("info", files["dir"] / "nope.laz")
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == f"gfjax: error: {files['dir'] / 'nope.laz'}: no such file or folder\n"
    done = _gfjax("dtm", files["truncated"], "-o", files["dir"] / "d.tif")
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "truncated or corrupt LAZ" in done.stderr
    assert not (files["dir"] / "d.tif").exists()
    done = _gfjax("--help")
    assert done.returncode == 0 and "info" in done.stdout and "filter" in done.stdout


def test_subprocess_enables_the_compilation_cache(tmp_path):
    script = ("import sys; from gfjax.cache import enable as e; folder = e(); "
              "import jax; c = jax.config; "
              "print(folder, c.jax_compilation_cache_dir, c.jax_persistent_cache_min_compile_time_secs, "
              "c.jax_compilation_cache_max_size)")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=120,
                          env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    folder = str(tmp_path / "gfjax" / "jax")
    size = "1073741824" if _has_filelock() else "-1"
    assert done.stdout.split() == [folder, folder, "0.0", size]
    # after `import jax` the settings go through jax.config
    script = script.replace("import sys;", "import sys, jax;")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=120,
                          env={**os.environ, "XDG_CACHE_HOME": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [folder, folder, "0.0", size]


def _has_filelock() -> bool:
    import importlib.util

    return importlib.util.find_spec("filelock") is not None
