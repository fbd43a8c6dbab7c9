"""Helpers of the whole-job reliability tests: a fake method that fails on chosen files, and
`gfjax` as a program with the fake methods registered (for signal tests)."""
from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import cli_helpers
import pytest

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
# sleeps (a signal then arrives while a temporary file exists).
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
sys.argv = ["gfjax", *sys.argv[1:]]
cli_main.main()
"""


def start_program(*argv, slow_write_from: int | None = None) -> subprocess.Popen:
    """Start `gfjax *argv` as a process (stdout, stderr piped, text)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "tests" / "cli"), str(REPO)])}
    if slow_write_from is not None:
        env["GFJAX_TEST_SLOW_WRITE"] = str(slow_write_from)
    return subprocess.Popen([sys.executable, "-c", PROGRAM, *map(str, argv)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)


def wait_for_line(process: subprocess.Popen, prefix: str, *, lines: list[str]) -> None:
    """Read stdout until a line starting with `prefix` (kept in `lines`); fail if it ends first."""
    for line in process.stdout:
        lines.append(line)
        if line.startswith(prefix):
            return
    raise AssertionError(f"process ended before {prefix!r}: {''.join(lines)} {process.stderr.read()}")
