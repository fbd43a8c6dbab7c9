"""The `gfjax` program ends without interpreter teardown (`cli.main._end_process`): outputs
are complete, the standard streams flushed, the exit code kept."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from cli_helpers import SCENE_CLASSES, write_scene

REPO = Path(__file__).resolve().parents[2]

# `gfjax` as the program (`main()` without argv), with the fake method of the in-process
# tests registered first (no JAX compile in a subprocess test).
_SETUP = """
import sys, types
import cli_helpers
from gfjax import methods
module = cli_helpers._fake_module("fake", instances=False)
sys.modules["_gfjax_test_fake"] = module
methods.PACKAGES["fake"] = "_gfjax_test_fake"
from gfjax.cli import main as cli_main
import gfjax.cache
gfjax.cache.setup = lambda: None
sys.argv = ["gfjax", *sys.argv[1:]]
"""
_PROGRAM = _SETUP + """
print("x" * 100_000, end="")                     # a large buffered write must still come out
cli_main.main()
raise SystemExit("main() returned")
"""


def _program(*argv, program: str = _PROGRAM, **kwargs) -> subprocess.CompletedProcess:
    kwargs = kwargs or {"capture_output": True}
    return subprocess.run([sys.executable, "-c", program, *map(str, argv)], text=True, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "tests" / "cli"), str(REPO)])},
                          timeout=120, **kwargs)


def _program_into_closed_pipe(*argv) -> subprocess.CompletedProcess:
    """Run `gfjax *argv` with its stdout a pipe whose reader has gone (`gfjax ... | head -1`)."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return _program(*argv, program=_SETUP + "cli_main.main()\n", stdout=write_end, stderr=subprocess.PIPE)
    finally:
        os.close(write_end)


def test_program_writes_its_output_and_flushes_before_exiting(tmp_path):
    source = write_scene(tmp_path / "in.las")
    target = tmp_path / "out.laz"
    done = _program("filter", source, "-o", target, "--method", "fake")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("x" * 100_000) and f"-> {target}: fake," in done.stdout
    assert "main() returned" not in done.stderr
    out = laspy.read(target)
    assert len(out.points) == len(SCENE_CLASSES)
    np.testing.assert_array_equal(out.intensity, laspy.read(source).intensity)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las", "out.laz"]     # no temporary left


def test_program_keeps_the_error_exit_code_and_message(tmp_path):
    done = _program("filter", tmp_path / "nope.las", "-o", tmp_path / "out.las", "--method", "fake")
    assert done.returncode == 2
    assert done.stderr.endswith(f"gfjax: error: {tmp_path / 'nope.las'}: no such file or folder\n")


def test_program_ends_quietly_with_141_when_its_reader_is_gone(tmp_path):
    """`gfjax info f.laz | head -1`: no message, 128 + SIGPIPE, as GNU tools and PDAL."""
    source = write_scene(tmp_path / "in.las")
    done = _program_into_closed_pipe("info", source)
    assert (done.returncode, done.stderr) == (141, "")


def test_program_whose_reader_is_gone_keeps_the_file_it_wrote(tmp_path):
    source = write_scene(tmp_path / "in.las")
    target = tmp_path / "out.laz"
    done = _program_into_closed_pipe("filter", source, "-o", target, "--method", "fake")
    assert (done.returncode, done.stderr) == (141, "")
    assert len(laspy.read(target).points) == len(SCENE_CLASSES)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las", "out.laz"]


def _mallopt_calls(monkeypatch) -> list[tuple[int, int]]:
    """The `mallopt(option, value)` calls `_tune_heap` makes, recorded instead of made."""
    import ctypes

    calls = []

    class Libc:
        def mallopt(self, option, value):
            calls.append((option, value))
            return 1

    monkeypatch.setattr(ctypes, "CDLL", lambda name: Libc())
    for name in ("MALLOC_ARENA_MAX", "MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_", "GLIBC_TUNABLES"):
        monkeypatch.delenv(name, raising=False)
    return calls


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap only")
def test_the_program_sets_the_heap_for_large_windows_once(monkeypatch):
    """`main()` as the program calls glibc's `mallopt` before any work: one arena per core,
    no block mapped apart, freed memory kept for reuse."""
    from gfjax.cli import main as cli_main

    calls = _mallopt_calls(monkeypatch)
    cli_main._tune_heap()
    assert calls == [(-8, os.cpu_count()), (-4, 0), (-1, cli_main._KEEP_FREED_BYTES)]
    assert 0 < cli_main._KEEP_FREED_BYTES < 2 ** 31                 # mallopt takes a C int


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap only")
@pytest.mark.parametrize(("name", "value", "kept"), [
    ("MALLOC_ARENA_MAX", "4", [(-4, 0), (-1, 1 << 30)]),
    ("MALLOC_MMAP_MAX_", "65536", [(-8, None)]),
    ("MALLOC_TRIM_THRESHOLD_", "131072", [(-8, None)]),
    ("GLIBC_TUNABLES", "glibc.malloc.trim_threshold=131072", []),
])
def test_the_users_own_heap_settings_win(monkeypatch, name, value, kept):
    from gfjax.cli import main as cli_main

    calls = _mallopt_calls(monkeypatch)
    monkeypatch.setenv(name, value)
    cli_main._tune_heap()
    assert [(option, os.cpu_count() if v is None else v) for option, v in kept] == calls


def test_a_call_with_arguments_leaves_the_heap_alone(monkeypatch, capsys):
    """Tests and other Python code call `main(argv)`: the process's allocator is theirs."""
    from gfjax.cli import main as cli_main

    calls = _mallopt_calls(monkeypatch)
    assert cli_main.main(["--version"]) == 0
    assert calls == []


def test_filtering_without_a_dtm_imports_no_plotting_or_spatial_library(tmp_path):
    """matplotlib and scipy.spatial (0.35 s of imports together) serve only the DTM: a
    `filter` without `--dtm` leaves them out of the process, which every first run pays."""
    src = write_scene(tmp_path / "in.las")
    program = _SETUP + """
code = cli_main.main(sys.argv[1:])
print(code, "matplotlib" in sys.modules, "scipy.spatial" in sys.modules)
"""
    done = _program("filter", src, "-o", tmp_path / "out.las", "--method", "fake", "--quiet", program=program)
    assert done.stdout.split()[-3:] == ["0", "False", "False"], done.stdout + done.stderr
