"""Strict JAX settings for every test, and the path to the shared labelled data."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import jax
import pytest

# Test modules are imported with --import-mode=importlib (same basenames in different folders
# are fine); helper modules (tests/reference.py, tests/<folder>/<name>.py) are found on this path.
# Names of helper modules must be unique across folders: tests/ comes first.
_TESTS = Path(__file__).resolve().parent
for _folder in [_TESTS, *sorted(p for p in _TESTS.iterdir() if p.is_dir() and not p.name.startswith((".", "_")))]:
    if str(_folder) not in sys.path:
        sys.path.append(str(_folder))

# The suite spends most of its time compiling programs that then run on a few thousand points,
# where LLVM's optimisation passes cost more than they save (a fifth of the suite's CPU time).
# Level 1 runs the cloth and the scattered groups' batches faster but compiles slower: a third
# of the suite (`pytest -n 2 tests/reliability tests/test_adaptive.py tests/csf tests/smrf
# tests/sparsegf/test_network.py tests/tiling tests/dmf tests/pmf`) took 597 s against 566 s.
# Worker processes and subprocesses inherit the setting. Speed is measured in experiments/,
# never here; GFJAX_TEST_XLA_OPT=1 keeps XLA's defaults.
_FAST_COMPILE = ("--xla_backend_optimization_level=0", "--xla_llvm_disable_expensive_passes=true")
if os.environ.get("GFJAX_TEST_XLA_OPT", "0") != "1":
    _flags = os.environ.get("XLA_FLAGS", "").split()
    os.environ["XLA_FLAGS"] = " ".join(_flags + [f for f in _FAST_COMPILE if f not in _flags])

# `gfjax.cli.main` turns on JAX's persistent compilation cache under $XDG_CACHE_HOME: keep the
# tests' cache out of the user's home, in one folder per test session, shared by the session's
# worker processes (they inherit the controller's environment).
if "GFJAX_TEST_KEEP_CACHE" not in os.environ:
    if "GFJAX_TEST_SESSION_CACHE" not in os.environ:
        import tempfile
        os.environ["GFJAX_TEST_SESSION_CACHE"] = tempfile.mkdtemp(prefix="gfjax-test-cache-")
    os.environ["XDG_CACHE_HOME"] = os.environ["GFJAX_TEST_SESSION_CACHE"]

# A method's first call in a process turns the persistent caches on (`gfjax.cache.ensure`).
# The tests' own process makes that call here with the caches off, so it keeps gfjax's program
# store off and each test sees plain jit unless it enables the store itself, but uses JAX's
# compilation cache in the session folder (GFJAX_TEST_JAX_CACHE=0: not even that).
# Subprocesses get the default (both caches on, in the folder above).
os.environ["GFJAX_CACHE"] = "0"
if os.environ.get("GFJAX_TYPECHECK", "1") == "1":
    # every annotated function of gfjax is checked at each call, jaxtyping's shapes and dtypes
    # included (tests/typecheck.py); GFJAX_TYPECHECK=0 turns it off. Tests that hand a bad
    # argument on purpose, to see our own check of it, turn it off for themselves (`unchecked`).
    import jaxtyping

    jaxtyping.install_import_hook("gfjax", "typecheck.checker")
import gfjax  # noqa: E402
from gfjax import cache as _cache  # noqa: E402

_cache.ensure()
del os.environ["GFJAX_CACHE"]
if os.environ.get("GFJAX_TEST_JAX_CACHE", "1") == "1":
    # a program one worker or subprocess compiled, another loads: the suite spends most of its
    # time compiling. It changes no result (tests/test_cache.py and tests/test_warmup.py check
    # the caches themselves, in folders of their own).
    _cache.enable()
    from gfjax import aot as _aot

    _aot.disable()

jax.config.update("jax_numpy_dtype_promotion", "strict")
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_enable_x64", False)


def _import_every_module() -> None:
    """Import every gfjax module now, while the session runs one thread.

    jaxtyping's import hook (above) parses each module's source as it is first imported, and
    CPython 3.11 counts an AST's depth in one place per process (python/cpython#106905): a
    module imported while another thread parses too (a Dask cluster's thread formatting a
    traceback does) can fail with "AST constructor recursion depth mismatch". A module whose
    optional dependency is absent is left to the tests that need it.
    """
    import importlib
    import pkgutil

    for module in pkgutil.walk_packages(gfjax.__path__, "gfjax."):
        try:
            importlib.import_module(module.name)
        except ModuleNotFoundError as err:
            if (err.name or "gfjax").startswith("gfjax"):
                raise


def pytest_configure(config):
    # not in xdist's controller, which runs no test
    controller = not hasattr(config, "workerinput") and bool(getattr(config.option, "numprocesses", None))
    if os.environ.get("GFJAX_TYPECHECK", "1") == "1" and not controller:
        _import_every_module()


SHARED_DATA = Path(os.environ.get("GFJAX_SHARED_DATA", Path(__file__).resolve().parents[1] / ".." / "shared" / "data")).resolve()
ISPRS = SHARED_DATA / "isprs_filtertest" / "reference"


def shared_file(relative: str) -> Path:
    """A file of `../shared/data`, or skip the test with a clear message when absent."""
    path = SHARED_DATA / relative
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set GFJAX_SHARED_DATA)")
    return path


@pytest.fixture
def isprs_sample():
    return lambda name: shared_file(f"isprs_filtertest/reference/{name}-utm.laz")


@pytest.fixture(autouse=True)
def _program_cache_off_after_each_test():
    """`gfjax.cli.main` turns `gfjax.aot` on for its process; an in-process CLI test must not
    leave it on for the next test of the same worker (it is off in the tests' process)."""
    yield
    from gfjax import aot

    aot.disable()


@pytest.fixture
def unchecked():
    """Type checking off for one test: what a user meets is our own check of a bad argument,
    not the test run's type checker."""
    import jaxtyping

    before = jaxtyping.config.jaxtyping_disable
    jaxtyping.config.update("jaxtyping_disable", True)
    yield
    jaxtyping.config.update("jaxtyping_disable", before)



def pytest_collection_modifyitems(config, items):
    """Tests marked `slow` (tens of seconds each: compiling in subprocesses, training,
    notebooks) run first, and idle workers steal queued tests (`--dist worksteal`,
    pyproject): the session then ends on short tests with both workers busy, instead of one
    worker finishing a notebook while the other waits."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
