"""`gfjax.aot`: compiled programs kept on disk across processes."""
from __future__ import annotations

import functools
import os
import subprocess
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import gfjax
from gfjax import aot, cache, dmf
from gfjax.aot import build, calls, keys, store

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "dmf"))
import dmf_scenes as scenes  # noqa: E402

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)


class Pair(NamedTuple):
    scaled: jax.Array
    total: jax.Array


@functools.partial(jax.jit, static_argnames=("factor",))
def scale_and_sum(x, mask, *, factor: int = 2) -> Pair:
    return Pair(scaled=x * factor, total=jnp.sum(jnp.where(mask, x, 0)))


def _call(fn, *args, **static):
    """`aot.call` for this module's functions: not gfjax's, so they need a tag."""
    return aot.call(fn, *args, tag=("tests.test_aot", fn.__name__), **static)


@pytest.fixture
def folder(tmp_path, monkeypatch):
    # as if this process had turned its caches on already: a method's first call in a test
    # worker would otherwise point the store at the session's folder (`cache.persistent`)
    monkeypatch.setitem(cache._state, "set_up", True)
    out = aot.enable(tmp_path / "export")
    assert out == tmp_path / "export"
    yield out
    aot.disable()


def _args(n=5, dtype=np.float32):
    return np.arange(n, dtype=dtype), np.arange(n) % 2 == 0


def _files(folder, kind=""):
    """Stored executables (kind ""), exported programs ("export") or plain-jit markers ("plain")."""
    return sorted(p for p in folder.glob("*.gfjaxexe") if p.name.count(".") == (2 if kind else 1)
                  and (not kind or p.name.endswith(f".{kind}.gfjaxexe")))


def _same(a, b):
    assert type(a) is type(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_off_is_the_plain_call(tmp_path):
    assert aot.enabled_folder() is None
    out = _call(scale_and_sum, *_args(), factor=3)
    _same(out, scale_and_sum(*_args(), factor=3))


def test_compiles_once_then_loads_from_disk(folder, monkeypatch):
    expected = scale_and_sum(*_args(), factor=3)
    _same(_call(scale_and_sum, *_args(), factor=3), expected)
    assert len(_files(folder)) == 1
    calls._loaded.clear()                                 # as a new process would start

    def no_compile(*_, **__):
        raise AssertionError("the stored program should have been loaded")

    monkeypatch.setattr(jax.stages.Lowered, "compile", no_compile)
    _same(_call(scale_and_sum, *_args(), factor=3), expected)


def test_on_compile_is_called_before_a_compile_not_a_load(folder):
    seen = []
    aot.on_compile(seen.append)
    try:
        _call(scale_and_sum, *_args(), factor=5)
        _call(scale_and_sum, *_args(), factor=5)          # in this process: no new compile
        calls._loaded.clear()                             # as a new process would start
        _call(scale_and_sum, *_args(), factor=5)          # loaded from the folder
    finally:
        aot.on_compile(None)
    assert seen == [__name__]


def test_a_new_process_loads_the_stored_program(folder):
    """A second interpreter finds the artifact the first one wrote (no compile there)."""
    script = (
        "import sys, jax, numpy as np\n"
        "sys.path.insert(0, sys.argv[2])\n"
        "from gfjax import aot\n"
        "import test_aot as t\n"
        "aot.enable(sys.argv[1])\n"
        "if sys.argv[3] == 'second':\n"
        "    jax.stages.Lowered.compile = None\n"
        "out = t._call(t.scale_and_sum, *t._args(7), factor=4)\n"
        "print(type(out).__name__, np.asarray(out.scaled).tolist(), int(out.total))\n")
    here = os.path.dirname(__file__)
    runs = [subprocess.run([sys.executable, "-c", script, str(folder), here, which], capture_output=True, text=True,
                           check=True).stdout.strip() for which in ("first", "second")]
    assert runs[0] == runs[1] == "Pair [0.0, 4.0, 8.0, 12.0, 16.0, 20.0, 24.0] 12"
    assert len(_files(folder)) == 1


def test_key_follows_shapes_dtypes_and_static_arguments():
    key = aot.program_key(scale_and_sum, _args(5), {"factor": 2})
    assert key == aot.program_key(scale_and_sum, _args(5), {"factor": 2})
    assert key != aot.program_key(scale_and_sum, _args(6), {"factor": 2})
    assert key != aot.program_key(scale_and_sum, _args(5, np.float64), {"factor": 2})
    assert key != aot.program_key(scale_and_sum, _args(5), {"factor": 3})
    x, mask = _args(5)
    strong, weak = jnp.asarray(np.float32(2.0)), jnp.asarray(2.0)     # float32 both; weak type differs
    assert aot.program_key(scale_and_sum, (x, strong), {}) != aot.program_key(scale_and_sum, (x, weak), {})


def test_one_file_per_program(folder):
    for n, factor in ((5, 2), (5, 3), (6, 2), (5, 2)):
        _same(_call(scale_and_sum, *_args(n), factor=factor), scale_and_sum(*_args(n), factor=factor))
    assert len(_files(folder)) == 3


@functools.partial(jax.jit, donate_argnums=0)
def add_into(state: Pair, x):
    return Pair(scaled=state.scaled + x, total=state.total + jnp.sum(x))


def test_a_stored_program_donates_what_its_jit_donates(folder):
    """A loop state handed from call to call: the stored program, compiled or loaded, writes
    its result into the donated state's buffers (the state is deleted), as plain jit does;
    the key says which arguments are donated."""
    x = np.arange(4, dtype=np.float32)

    def state():
        return Pair(jnp.zeros(4, jnp.float32), jnp.zeros((), jnp.float32))

    assert keys.donated(add_into) == (0,) and keys.donated(scale_and_sum) == ()
    assert keys.donated_leaves(add_into, (state(), x)) == (0, 1)
    for _ in range(2):                                    # compiled and stored, then loaded
        before = state()
        out = _call(add_into, _call(add_into, before, x), x)
        assert before.scaled.is_deleted() and before.total.is_deleted()
        np.testing.assert_array_equal(out.scaled, 2 * x)
        assert float(out.total) == 12.0
        calls._loaded.clear()                             # as a new process would start
    assert len(_files(folder)) == 1
    plain = jax.jit(add_into.__wrapped__)
    assert aot.program_key(add_into, (state(), x), {}, tag="t") != aot.program_key(plain, (state(), x), {}, tag="t")


def test_corrupt_artifact_is_compiled_again(folder):
    _call(scale_and_sum, *_args(), factor=3)
    (path,) = _files(folder)
    path.write_bytes(b"not a program")
    calls._loaded.clear()
    _same(_call(scale_and_sum, *_args(), factor=3), scale_and_sum(*_args(), factor=3))
    assert path.stat().st_size > 100


def test_unwritable_folder_is_no_error(folder, monkeypatch):
    real_open = os.open

    def refuse(path, flags, *args, **kwargs):
        if flags & os.O_CREAT and "dir_fd" in kwargs:
            raise PermissionError("read-only cache")
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(store.os, "open", refuse)
    _same(_call(scale_and_sum, *_args(), factor=5), scale_and_sum(*_args(), factor=5))
    assert _files(folder) == []


def test_traced_arguments_take_the_plain_path(folder):
    """Under jit, vmap and grad the arguments are tracers: `call` is `fn(*args)`, no file."""
    x, mask = _args()
    jitted = jax.jit(lambda a: _call(scale_and_sum, a, mask, factor=2).total)
    assert float(jitted(x)) == float(scale_and_sum(x, mask).total)
    batched = jax.vmap(lambda a: _call(scale_and_sum, a, mask, factor=2).scaled)(np.stack([x, x + 1]))
    np.testing.assert_array_equal(batched, np.stack([x * 2, (x + 1) * 2]))
    grad = jax.grad(lambda a: _call(scale_and_sum, a, mask, factor=2).total)(x)
    np.testing.assert_array_equal(grad, mask.astype(np.float32))
    assert _files(folder) == []


def test_least_recently_used_are_pruned(folder, monkeypatch):
    monkeypatch.setattr(store, "MAX_FILES", 2)
    for n in (3, 4, 5, 6):
        _call(scale_and_sum, *_args(n), factor=2)
    assert len(_files(folder)) == 2
    newest = {p.name for p in _files(folder)}
    calls._loaded.clear()
    _call(scale_and_sum, *_args(6), factor=2)               # a load refreshes its file
    _call(scale_and_sum, *_args(7), factor=2)
    assert len(_files(folder)) == 2 and len(newest & {p.name for p in _files(folder)}) == 1


def test_pruned_to_the_byte_bound(folder, monkeypatch):
    _call(scale_and_sum, *_args(3), factor=2)
    (first,) = _files(folder)
    monkeypatch.setattr(store, "MAX_BYTES", int(first.stat().st_size * 1.5))
    _call(scale_and_sum, *_args(4), factor=2)
    assert len(_files(folder)) == 1 and not first.exists()


def test_key_follows_the_machine(monkeypatch):
    """An executable is machine code: another CPU (instruction-set flags) is another key."""
    key = aot.program_key(scale_and_sum, _args(5), {"factor": 2})
    monkeypatch.setitem(keys._state, "fingerprint", None)
    monkeypatch.setattr(keys, "_cpu_flags", lambda: "fpu sse2")
    assert aot.program_key(scale_and_sum, _args(5), {"factor": 2}) != key
    monkeypatch.setitem(keys._state, "fingerprint", None)


def test_dmf_through_the_cache_equals_the_plain_call(folder):
    """DMF's programs (basal loop, raster stages, the final rule's fill and test) compiled, stored, reloaded:
    labels, instances and every diagnostic raster equal the plain jitted path."""
    cloud, _, _ = scenes.box_scene()
    aot.disable()
    plain = dmf.filter(cloud)
    aot.enable(folder)
    exported = dmf.filter(cloud)
    assert len(_files(folder)) == 4
    calls._loaded.clear()
    loaded = dmf.filter(cloud)
    for result in (exported, loaded):
        np.testing.assert_array_equal(result.ground, plain.ground)
        np.testing.assert_array_equal(result.instance_id, plain.instance_id)
        for name in ("basal_z", "ngnem", "rhc", "ngnem_bi", "ngnem_rc0", "ngnem_rc", "instances"):
            np.testing.assert_array_equal(getattr(result.diagnostics, name), getattr(plain.diagnostics, name))
        assert result.diagnostics.basal_iterations == plain.diagnostics.basal_iterations


@pytest.mark.parametrize("setting, expected", [(None, "default"), ("", None), ("0", None), ("/tmp/gfjax-x", "/tmp/gfjax-x")])
def test_export_cache_folder(monkeypatch, setting, expected):
    if setting is None:
        monkeypatch.delenv("GFJAX_EXPORT_CACHE", raising=False)
    else:
        monkeypatch.setenv("GFJAX_EXPORT_CACHE", setting)
    folder = cache.export_folder()
    if expected == "default":
        assert folder == cache.folder().parent / "export"
    else:
        assert folder == (None if expected is None else type(folder)(expected))


def test_an_executable_from_jax_cache_is_not_stored(folder, monkeypatch):
    """JAX's compilation cache gives executables that serialize incompletely: `call` uses
    them in this process but stores nothing."""
    compile_ = jax.stages.Lowered.compile

    def from_cache(self, *args, **kwargs):
        jax.monitoring.record_event("/jax/compilation_cache/cache_hits")
        return compile_(self, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Lowered, "compile", from_cache)
    _same(_call(scale_and_sum, *_args(9), factor=2), scale_and_sum(*_args(9), factor=2))
    assert _files(folder) == []


_PROCESS = r"""
import sys, numpy as np, jax
sys.path.insert(0, sys.argv[3])
jax.config.update("jax_compilation_cache_dir", sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
import gfjax
from gfjax import aot, dmf
import dmf_scenes as scenes
if sys.argv[2] != "-":
    aot.enable(sys.argv[2])
cloud, _, _ = scenes.box_scene()
result = dmf.filter(cloud)
print(int(result.ground.sum()), int(result.instance_id.sum()), int(result.diagnostics.ngnem_rc.sum()))
"""


def test_stored_programs_run_in_a_new_process_when_jax_cache_is_warm(tmp_path):
    """The case that broke: JAX's persistent cache already holds DMF's programs (plain jit), a
    second process stores them through `aot`, a third loads and runs them."""
    jax_cache, export = tmp_path / "jax", tmp_path / "export"
    here = os.path.join(os.path.dirname(__file__), "dmf")

    def run(export_folder):
        return subprocess.run([sys.executable, "-c", _PROCESS, str(jax_cache), export_folder, here],
                              capture_output=True, text=True, check=True,
                              env={**os.environ, "GFJAX_CACHE": "0"}).stdout.strip()

    plain = run("-")
    assert run(str(export)) == plain
    assert len(list(export.glob("*.gfjaxexe"))) == 4
    assert run(str(export)) == plain


def test_prefetch_loads_what_call_runs(folder, monkeypatch):
    spec = jax.ShapeDtypeStruct
    aot.prefetch(scale_and_sum, spec((4,), np.float32), spec((4,), np.bool_), factor=3,
                 tag=("tests.test_aot", "scale_and_sum"))
    assert len(_files(folder)) == 1 and len(calls._loaded) == 1
    monkeypatch.setattr(jax.stages.Lowered, "compile", lambda *_, **__: pytest.fail("prefetched program compiled again"))
    _same(_call(scale_and_sum, *_args(4), factor=3), scale_and_sum(*_args(4), factor=3))


def test_prefetch_is_nothing_when_off(tmp_path):
    aot.prefetch(scale_and_sum, jax.ShapeDtypeStruct((4,), np.float32), jax.ShapeDtypeStruct((4,), np.bool_),
                 tag=("tests.test_aot", "scale_and_sum"))
    assert calls._loaded == {}


@jax.jit
def solve(a, b):
    return jnp.linalg.solve(a, b)                     # LAPACK custom calls on CPU


def test_program_with_custom_calls_is_exported(folder, monkeypatch):
    """Executables with XLA custom calls (LAPACK, FFT) crash in another process: such a
    program is kept as exported StableHLO instead, and a new process skips its tracing."""
    a = np.array([[3.0, 1.0], [1.0, 2.0]], np.float32)
    b = np.array([9.0, 8.0], np.float32)
    np.testing.assert_allclose(_call(solve, a, b), np.linalg.solve(a, b), rtol=1e-6)
    assert _files(folder) == [] and len(_files(folder, "export")) == 1
    calls._loaded.clear()                                 # as a new process would start
    monkeypatch.setattr(jax.export, "export", lambda *_, **__: pytest.fail("the stored export should be loaded"))
    monkeypatch.setattr(build, "compile_fresh", lambda *_: pytest.fail("the stored export should be loaded"))
    np.testing.assert_allclose(_call(solve, a, b), np.linalg.solve(a, b), rtol=1e-6)


def test_program_that_cannot_be_stored_runs_through_plain_jit(folder, monkeypatch):
    """Without flatbuffers (jax.export's format) a program with custom calls is not stored;
    a marker sends later processes straight to plain jit."""
    real = build.importlib.util.find_spec
    monkeypatch.setattr(build.importlib.util, "find_spec", lambda name: None if name == "flatbuffers" else real(name))
    a = np.array([[2.0, 0.0], [0.0, 4.0]], np.float32)
    b = np.array([2.0, 8.0], np.float32)
    np.testing.assert_allclose(_call(solve, a, b), [1.0, 2.0], rtol=1e-6)
    assert _files(folder) == [] and _files(folder, "export") == [] and len(_files(folder, "plain")) == 1
    calls._plain.clear()
    monkeypatch.setattr(build, "compile_fresh", lambda *_: pytest.fail("the marker should skip the compile"))
    np.testing.assert_allclose(_call(solve, a, b), [1.0, 2.0], rtol=1e-6)


@pytest.mark.parametrize("method, stored", [("smrf", (3, 0)), ("pmf", (3, 0)), ("csf", (5, 0))])
def test_method_through_the_cache_equals_the_plain_call(folder, method, stored):
    """A method's programs (three each, CSF five: its cloth is three; stored as executables:
    none holds a custom call, so none is exported), reloaded as in a new process: the same
    labels, with a progress bar too (CSF's cloth then runs a chunk per call, its state donated)."""
    module = getattr(gfjax, method)
    cloud, _, _ = scenes.box_scene()
    aot.disable()
    plain = module.filter(cloud)
    aot.enable(folder)
    first = module.filter(cloud)
    assert (len(_files(folder)), len(_files(folder, "export"))) == stored
    calls._loaded.clear()
    loaded = module.filter(cloud)
    shown = module.filter(cloud, progress=True)
    assert len(_files(folder)) == stored[0]
    for result in (first, loaded, shown):
        np.testing.assert_array_equal(result.ground, plain.ground)


def test_functions_the_key_cannot_tell_apart_take_plain_jit(folder):
    """Untagged functions from outside gfjax, closures and partials: their code or what they
    bind is not in the key, so they run through plain jit and nothing is stored."""
    def make(k):
        return jax.jit(lambda x: x * k)

    x = np.ones(3, np.float32)
    np.testing.assert_array_equal(aot.call(scale_and_sum, x, x > 0).scaled, x * 2)
    np.testing.assert_array_equal(aot.call(make(3), x), x * 3)
    np.testing.assert_array_equal(aot.call(make(4), x), x * 4)
    np.testing.assert_array_equal(aot.call(jax.jit(functools.partial(scale_and_sum, factor=5)), x, x > 0).scaled, x * 5)
    assert list(folder.iterdir()) == []


def test_output_that_does_not_survive_pickling_is_not_stored(folder):
    """An equinox module's pickled pytree definition does not unflatten again: such a
    program runs, and later processes take plain jit (a marker says so)."""
    import equinox as eqx

    class Box(eqx.Module):
        value: jax.Array

    @jax.jit
    def boxed(x):
        return Box(x * 2)

    out = aot.call(boxed, np.ones(2, np.float32), tag=("tests.test_aot", "boxed"))
    np.testing.assert_array_equal(out.value, [2.0, 2.0])
    assert _files(folder) == [] and len(_files(folder, "plain")) == 1


def test_folder_others_can_write_is_refused(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    assert aot.enable(shared) is None and aot.enabled_folder() is None
    private = aot.enable(tmp_path / "private")
    assert private is not None and private.stat().st_mode & 0o777 == 0o700
    aot.disable()


def test_failed_write_leaves_no_temporary_file(folder, monkeypatch):
    def full(*_, **__):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(store.os, "replace", full)
    _same(_call(scale_and_sum, *_args(3), factor=2), scale_and_sum(*_args(3), factor=2))
    assert [p.name for p in folder.iterdir() if p.name.endswith(".tmp")] == []


def test_prefetching_prepares_the_program_a_call_of_those_shapes_runs(folder, monkeypatch):
    spec = jax.ShapeDtypeStruct
    with aot.prefetching():
        out = _call(scale_and_sum, spec((4,), np.float32), spec((4,), np.bool_), factor=3)
    assert jax.tree.map(lambda a: (a.shape, a.dtype), out) == \
        jax.tree.map(lambda a: (a.shape, a.dtype), jax.eval_shape(lambda *a: scale_and_sum(*a, factor=3), *_args(4)))
    assert len(_files(folder)) == 1
    monkeypatch.setattr(jax.stages.Lowered, "compile", lambda *_, **__: pytest.fail("prefetched program compiled again"))
    _same(_call(scale_and_sum, *_args(4), factor=3), scale_and_sum(*_args(4), factor=3))


def test_prefetching_an_exported_program_compiles_it_too(folder):
    a = jax.ShapeDtypeStruct((2, 2), np.float32)
    with aot.prefetching():
        out = _call(solve, a, jax.ShapeDtypeStruct((2,), np.float32))
    assert out.shape == (2,) and len(_files(folder, "export")) == 1
    (program,) = calls._loaded.values()
    assert hasattr(program, "compile")            # its executable went to JAX's cache as well


def test_release_drops_the_programs_this_process_holds():
    import jax
    import jax.numpy as jnp

    from gfjax import aot

    @jax.jit
    def double(x):
        return 2 * x

    double(jnp.ones(3))
    assert double._cache_size() == 1
    aot.release()
    assert double._cache_size() == 0
    np.testing.assert_array_equal(double(jnp.ones(3)), 2 * np.ones(3))     # compiled again on demand
