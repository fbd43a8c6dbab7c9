"""A program built to be stored: compiled outside JAX's persistent cache, or exported.

A program without XLA custom calls is compiled here (`compile_fresh`) and its executable stored;
one with custom calls (LAPACK on CPU) is exported instead (`export_program`, `jax.export`,
StableHLO): a later process skips its tracing, lowers a thin wrapper and compiles through JAX's
persistent cache. Either takes the leaves of its arguments (`_leaf_program`).
"""
from __future__ import annotations

import importlib.util
import pickle
import threading

from gfjax.aot import store
from gfjax.aot.keys import donated_leaves, dtype_of, name_of

__all__ = ["compile_fresh", "export_program"]

_lock = threading.Lock()              # one compile at a time, where JAX has no per-thread option
_hits = threading.local()             # JAX cache hits seen by this thread's compile
_state = {"watching": False}          # the listener of `_hits` is registered


def compile_fresh(fn, args, static):
    """Compile `fn(*args, **static)` outside JAX's persistent compilation cache.

    An executable that JAX loaded from its cache serializes incompletely (jaxlib 0.10.2, CPU:
    a later process fails with "Function ... not found"), so the program is lowered under a
    name of its own (`gfjax_aot_<name>`: its own cache key, never an entry written by plain
    `jit`) and compiled with cache writes off for this thread, so its key never enters that
    cache either.
    The stored program takes the leaves of `args` (a pickled pytree definition of, say, an
    equinox module does not unflatten again). A program with XLA custom calls (LAPACK on CPU:
    bound to the compiling process) is not compiled here: its executable crashes when run in
    another process (SMRF's harmonic fill, jaxlib 0.10.2 CPU: a segmentation fault).

    The arguments `fn`'s `jax.jit` donates are donated by the stored program too.

    Returns: `(compiled, fresh)`: `(None, False)` for a program with custom calls; `fresh` is
    False if JAX reports a cache hit all the same (then it is used but not stored).
    """
    import jax

    program, leaves = _leaf_program(fn, args, static)
    lowered = jax.jit(program, donate_argnums=donated_leaves(fn, args)).lower(*leaves)
    if "custom_call" in lowered.as_text():
        return None, False
    _watch_cache_hits()
    _hits.count = 0
    try:                              # this thread only: other threads keep writing the cache
        from jax._src import config as jax_config

        no_writes = jax_config.persistent_cache_min_compile_time_secs(float("inf"))
    except Exception:  # pragma: no cover (another JAX: the global option, one compile at a time)
        no_writes = None
    if no_writes is not None:
        with no_writes:
            compiled = lowered.compile()
    else:  # pragma: no cover
        with _lock:
            before = jax.config.jax_persistent_cache_min_compile_time_secs
            jax.config.update("jax_persistent_cache_min_compile_time_secs", float("inf"))
            try:
                compiled = lowered.compile()
            finally:
                jax.config.update("jax_persistent_cache_min_compile_time_secs", before)
    return compiled, _hits.count == 0


def export_program(fn, args, static):
    """`(program, blob)`: the program exported with `jax.export` (StableHLO; custom calls are
    kept by name, so it stays valid in another process, which lowers a thin wrapper around it
    and compiles through JAX's persistent cache), as a function of the leaves of `args`, and
    its serialized form; `(None, None)` when it cannot be exported or serialized (no
    `flatbuffers`, or a custom call jax.export does not guarantee)."""
    import jax
    import numpy as np
    from jax import export

    if importlib.util.find_spec("flatbuffers") is None:    # jax.export's serialization format
        return None, None
    out = {}
    program, leaves = _leaf_program(fn, args, static, out=out)
    try:
        specs = [jax.ShapeDtypeStruct(np.shape(a), dtype_of(a)) for a in leaves]
        exported = export.export(jax.jit(program))(*specs)
        blob = pickle.dumps((bytes(exported.serialize()), out["tree"]), protocol=pickle.HIGHEST_PROTOCOL)
        if not store.tree_survives(out["tree"]):
            return None, None
    except Exception:
        return None, None
    return store.exported_program(exported, out["tree"]), blob


def _leaf_program(fn, args, static, *, out: dict | None = None):
    """`(program, leaves)`: `fn(*args, **static)` as a function of the leaves of `args`, named
    `gfjax_aot_<name>`. With `out`, the program returns the leaves of its result and puts their
    pytree definition in `out["tree"]` when traced."""
    import jax

    leaves, treedef = jax.tree.flatten(args)

    def program(*arrays):
        result = fn(*jax.tree.unflatten(treedef, arrays), **static)
        if out is None:
            return result
        flat, out["tree"] = jax.tree.flatten(result)
        return flat

    program.__name__ = program.__qualname__ = f"gfjax_aot_{(name_of(fn) or 'program').replace('.', '_')}"
    return program, leaves


def _watch_cache_hits() -> None:
    if _state["watching"]:
        return
    import jax

    def listen(event: str, **_):
        if event == "/jax/compilation_cache/cache_hits":
            _hits.count = getattr(_hits, "count", 0) + 1

    jax.monitoring.register_event_listener(listen)
    _state["watching"] = True
