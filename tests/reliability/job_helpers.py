"""Helpers of the whole-job reliability tests: a fake method that fails on chosen files, and
`gfjax` as a program with the fake methods registered (for signal tests)."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest

import cli_helpers
from gfjax.errors import InputError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def picky_method(monkeypatch):
    """Method "picky": the fake filter of `cli_helpers`, but a file whose name holds "bad"
    fails with bad input, one holding "bug" with an internal error, and "noground" gets no
    ground point."""
    from gfjax import methods

    module = cli_helpers._fake_module("picky", instances=False)
    inner = module.filter

    def filter(cloud, **kwargs):  # noqa: A001
        name = os.path.basename(cloud.name)
        if "bad" in name:
            raise InputError(f"{cloud.name}: this file fails while it is filtered")
        if "bug" in name:
            raise RuntimeError("fake bug")
        result = inner(cloud, **kwargs)
        if "noground" in name:
            result = result._replace(ground=result.ground & False)
        return result

    module.filter = filter
    module.METHOD = dataclasses.replace(module.METHOD, filter=filter)
    monkeypatch.setitem(sys.modules, "_gfjax_test_picky", module)
    monkeypatch.setitem(methods.PACKAGES, "picky", "_gfjax_test_picky")
    return module


# `gfjax` as the program (`main()` without argv), the fake method registered first; with
# GFJAX_TEST_SLOW_WRITE set, every LAS write writes its points, prints "WRITING <n>" and
# sleeps (a signal then arrives while a temporary file exists); with GFJAX_TEST_SLOW_FILE
# set, the first write of point bytes into the output file sleeps instead (a signal then
# arrives inside the LAS/LAZ writer's call back into Python, as a real slow disk would have it).
PROGRAM = """
import os, sys, time
import cli_helpers, laspy
from gfjax import methods
module = cli_helpers._fake_module("fake", instances=False)
sys.modules["_gfjax_test_fake"] = module
methods.PACKAGES["fake"] = "_gfjax_test_fake"
from gfjax.cli import main as cli_main
import gfjax.cache
gfjax.cache.setup = lambda: None
if os.environ.get("GFJAX_TEST_SLOW_WRITE"):
    from gfjax.io import las as las_io
    real_write, count = las_io._write_las, [0]
    def slow_write(*args, **kwargs):
        real_write(*args, **kwargs)
        count[0] += 1
        if count[0] >= int(os.environ["GFJAX_TEST_SLOW_WRITE"]):
            print(f"WRITING {count[0]}", flush=True)
            time.sleep(60)
    las_io._write_las = slow_write
if os.environ.get("GFJAX_TEST_SLOW_FILE"):
    from gfjax.io import las as las_io
    real_write_las = las_io._write_las
    class SlowFile:
        def __init__(self, f):
            self.f, self.slept = f, False
        def write(self, data):
            header = sys._getframe(1).f_code.co_name in ("write_to", "write_initial_header_and_vlrs")
            if not self.slept and not header:      # the points: for LAZ, lazrs calls this from Rust
                self.slept = True
                print("WRITING 1", flush=True)
                time.sleep(60)
            return self.f.write(data)
        def __getattr__(self, name):
            return getattr(self.f, name)
    las_io._write_las = lambda las, f, **kwargs: real_write_las(las, SlowFile(f), **kwargs)
sys.argv = ["gfjax", *sys.argv[1:]]
cli_main.main()
"""


def start_program(*argv, slow_write_from: int | None = None, slow_file: bool = False) -> subprocess.Popen:
    """Start `gfjax *argv` as a process (stdout, stderr piped, text)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "tests" / "cli"), str(REPO)])}
    if slow_write_from is not None:
        env["GFJAX_TEST_SLOW_WRITE"] = str(slow_write_from)
    if slow_file:
        env["GFJAX_TEST_SLOW_FILE"] = "1"
    return subprocess.Popen([sys.executable, "-c", PROGRAM, *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)


def wait_for_line(process: subprocess.Popen, prefix: str, *, lines: list[str]) -> None:
    """Read stdout until a line starting with `prefix` (kept in `lines`); fail if it ends first."""
    for line in process.stdout:
        lines.append(line)
        if line.startswith(prefix):
            return
    raise AssertionError(f"process ended before {prefix!r}: {''.join(lines)} {process.stderr.read()}")
