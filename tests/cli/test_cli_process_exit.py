"""The `gfjax` program ends without interpreter teardown (`cli.main._end_process`): outputs
are complete, the standard streams flushed, the exit code kept."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
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


def test_the_program_sets_its_heap_and_a_call_with_arguments_leaves_it_alone(monkeypatch, capsys):
    """`main()` as the program sets the heap (`gfjax.heap.tune`) before any work; tests and
    other Python code call `main(argv)`: the process's allocator is theirs."""
    from gfjax import heap
    from gfjax.cli import main as cli_main

    calls = []

    def end(code):
        calls.append(code)
        raise SystemExit(code)

    monkeypatch.setattr(heap, "tune", lambda: calls.append("tune"))
    monkeypatch.setattr(cli_main, "_end_process", end)
    monkeypatch.setattr(sys, "argv", ["gfjax", "--version"])
    try:
        cli_main.main()
    except SystemExit:
        pass
    assert calls == ["tune", 0]
    calls.clear()
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
