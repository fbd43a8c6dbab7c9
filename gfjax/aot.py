"""Jitted programs kept across processes: compiled executables (or exported StableHLO) on disk.

A new `gfjax filter` process pays, per jitted program, tracing (Python), lowering (MLIR),
hashing the module for JAX's persistent compilation cache and loading the executable from
it. For DMF on an 824 k point tile that was 0.5 s of a 1.7 s process. `call(fn, *args,
**static)` pays it once: the program `fn(*args, **static)` is compiled (outside JAX's
compilation cache, see `_compile_fresh`), its executable serialized into `folder`
(`jax.experimental.serialize_executable`), and later processes load it and call it: no
tracing, no lowering, no hashing. A program with XLA custom calls (LAPACK on CPU) is exported
instead (`jax.export`, StableHLO): a later process skips tracing and lowers a thin wrapper,
and compiles through JAX's persistent cache.

Off by default (`call` is then `fn(*args, **static)`); `gfjax.cli` turns it on next to the
compilation cache, and `enable(folder)` does so in a notebook or a batch script. This module
imports JAX only when a program is called (`gfjax info` stays fast).

The key of a program: `fn`'s module and name, the static keyword arguments (their `repr`),
each argument's shape, dtype and weak type, the JAX and jaxlib versions, the backend and device kind,
the host CPU (machine and instruction-set flags: an executable is machine code), `XLA_FLAGS`,
the JAX options that change tracing, and a hash of the gfjax source files, so a change of
gfjax code, JAX, jaxlib or machine never runs a stale program. Only module-level gfjax
functions are cached by name; a closure or `functools.partial` needs a `tag` naming all it
binds (gfjax's callers give one), and anything else takes plain jit. Arguments must be
concrete (numpy or JAX arrays, numpy scalars): under `jit`, `vmap` or `grad`, `call` is
`fn(*args, **static)`. A missing, unreadable or stale artifact is compiled again; a program
that cannot be stored (custom calls that cannot be exported, an output pytree that does not
survive pickling) leaves a marker and runs through plain jit in later processes.

The files hold pickled pytree definitions next to the executable, so `enable` refuses a
folder that other users can write (it creates it with mode 0700; files are 0600).
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import os
import pickle
import platform
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

__all__ = ["enable", "disable", "enabled_folder", "call", "prefetch", "program_key", "MAX_FILES", "MAX_BYTES"]

MAX_FILES = 512                 # artifacts kept (least recently used go first); each is ~0.1-2 MB
MAX_BYTES = 256 * 2**20         # ... and their total size
_SUFFIX = ".gfjaxexe"
_EXPORT_SUFFIX = ".export" + _SUFFIX  # a program with custom calls: exported StableHLO
_PLAIN_SUFFIX = ".plain" + _SUFFIX    # marker: this program is not stored, run it through plain jit

_state: dict[str, Any] = {"folder": None, "fingerprint": None}
_loaded: dict[str, Any] = {}    # key -> program of the argument leaves, for this process
_plain: set[str] = set()        # keys of programs that run through plain jit (custom calls)
_lock = threading.Lock()        # one compile at a time (`_compile_fresh`)


def enable(folder: str | os.PathLike) -> Path | None:
    """Keep compiled programs in `folder` (created with mode 0700 if needed). Returns it, or
    None (and the cache stays off) when it cannot be created, is not writable, or is not
    private to this user (the files are unpickled: a folder others can write is refused)."""
    folder = Path(folder)
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
        stat = folder.stat()
    except OSError:
        return None
    if not os.access(folder, os.W_OK | os.X_OK) or stat.st_mode & 0o022 or (
            hasattr(os, "geteuid") and stat.st_uid != os.geteuid()):
        return None
    _state["folder"] = folder
    return folder


def disable() -> None:
    """Turn the cache off (`call` is then `fn(*args, **static)`)."""
    _state["folder"] = None
    _loaded.clear()
    _plain.clear()


def enabled_folder() -> Path | None:
    """The cache folder, or None when the cache is off."""
    return _state["folder"]


def _cpu_flags() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as file:
            for line in file:
                if line.startswith(("flags", "Features")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def _fingerprint() -> str:
    """sha256 of what makes an executable valid here, once per process: every
    `gfjax/**/*.py` (path and bytes), the JAX/jaxlib versions, backend, device kind, CPU."""
    if _state["fingerprint"] is None:
        import jax
        import jaxlib

        root = Path(__file__).resolve().parent
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        device = jax.devices()[0]
        try:
            from jax.extend import backend as jax_backend

            platform_version = jax_backend.get_backend().platform_version
        except Exception:  # pragma: no cover (another JAX)
            platform_version = ""
        for part in (jax.__version__, jaxlib.__version__, device.platform, device.device_kind,
                     platform_version, platform.machine(), _cpu_flags(),
                     os.environ.get("XLA_FLAGS", ""), importlib.util.find_spec("flatbuffers") is not None):
            digest.update(str(part).encode() + b"\0")
        _state["fingerprint"] = digest.hexdigest()
    return _state["fingerprint"]


def _concrete(x) -> bool:
    import jax
    import numpy as np

    return isinstance(x, (np.ndarray, np.generic)) or (isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer))


def _dtype(x):
    import numpy as np

    return np.dtype(x.dtype) if hasattr(x, "dtype") else np.result_type(x)


def _name(fn) -> str | None:
    return getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None)


def _cacheable(fn, tag) -> bool:
    """A program the key can tell apart: tagged, or a module-level gfjax function (its code is
    in the fingerprint). Closures, partials and functions from elsewhere take plain jit."""
    if tag is not None:
        return True
    name, module = _name(fn), getattr(fn, "__module__", None) or ""
    return bool(name) and "<locals>" not in name and (module == "gfjax" or module.startswith("gfjax."))


def _trace_options() -> str:
    """The JAX options that enter jit's own cache key (default device, PRNG, x64, promotion,
    ...), or, should that private tuple move or show object addresses, the main ones."""
    import jax

    try:
        from jax._src import config as jax_config

        text = repr(jax_config.trace_context())
        if " at 0x" not in text:
            return text
    except Exception:  # pragma: no cover (another JAX)
        pass
    names = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_dtype_promotion", "jax_default_device",
             "jax_threefry_partitionable", "jax_default_prng_impl")
    return repr([(name, getattr(jax.config, name, None)) for name in names])


def program_key(fn: Callable, args: tuple, static: dict, tag=None) -> str:
    """The cache key of `fn(*args, **static)` (hex sha256; see the module docstring). `tag`,
    when given, names the program instead of `fn`'s module and name."""
    import jax
    import numpy as np

    leaves, treedef = jax.tree.flatten(args)
    signature = [f"{np.shape(a)}:{_dtype(a)}:{'weak' if getattr(a, 'weak_type', False) else ''}:"
                 f"{a.sharding if isinstance(a, jax.Array) and a.committed else ''}" for a in leaves]
    name = repr(tag) if tag is not None else f"{fn.__module__}.{_name(fn)}"
    parts = [name, repr(sorted(static.items())), str(treedef), ";".join(signature), _trace_options(), _fingerprint()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _load(path: Path):
    """The stored executable at `path`, or None (unreadable or stale: compile again)."""
    from jax.experimental import serialize_executable

    return _read(path, lambda payload: serialize_executable.deserialize_and_load(*payload))


def _read(path: Path, build):
    """`build(unpickled contents of path)`, or None when that fails; a hit refreshes the
    file's time (least recently used files go first)."""
    try:
        program = build(pickle.loads(path.read_bytes()))
    except Exception:
        return None
    with contextlib.suppress(OSError):
        os.utime(path)
    return program


def _store(compiled, folder: Path, key: str) -> bool:
    """Store `compiled`; False when it cannot be (its output pytree does not survive pickling,
    e.g. an equinox module, or the folder cannot be written)."""
    from jax.experimental import serialize_executable

    try:
        payload = serialize_executable.serialize(compiled)
        blob = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
        if not _tree_survives(payload[2]):
            return False
    except Exception:                                       # a program that cannot be stored is no error
        return False
    return _write(folder, f"{key}{_SUFFIX}", blob)


def _tree_survives(tree) -> bool:
    """Whether a pytree definition unflattens again after pickling (an equinox module's does
    not: its pickled definition holds a sentinel)."""
    try:
        pickle.loads(pickle.dumps(tree)).unflatten([0] * tree.num_leaves)
        return True
    except Exception:
        return False


def _write(folder: Path, name: str, blob: bytes) -> bool:
    """Write `folder / name` atomically (readers never see half a file), then prune. Returns
    whether it was written; a failed write leaves no temporary file."""
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name[:16]}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as file:
            file.write(blob)
        os.replace(tmp, folder / name)
    except Exception:                                       # a cache that cannot be written is no error
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        return False
    with contextlib.suppress(Exception):
        _prune(folder)
    return True


def _prune(folder: Path) -> None:
    """Remove the least recently used artifacts beyond `MAX_FILES` or `MAX_BYTES` (programs
    of older gfjax sources are never used again and go first)."""
    stats = []
    for path in folder.glob(f"*{_SUFFIX}"):
        try:
            stat = path.stat()
        except OSError:                                     # removed by another process
            continue
        stats.append((stat.st_mtime, stat.st_size, path))
    stats.sort(key=lambda item: item[0], reverse=True)      # newest first
    total = 0
    for count, (_, size, path) in enumerate(stats, start=1):
        total += size
        if count > MAX_FILES or total > MAX_BYTES:
            path.unlink(missing_ok=True)


def call(fn: Callable, *args, tag=None, **static):
    """`fn(*args, **static)`, through the on-disk program cache when it is on.

    Args:
      fn: a `jax.jit`-wrapped function whose keyword arguments `static` are all static
        (hashable; their `repr` enters the key).
      args: pytrees of concrete arrays (numpy or JAX) or numpy scalars.
      tag: names the program in the key instead of `fn`'s module and name; needed when `fn`
        is a closure or a `functools.partial` (give everything it binds, e.g. its config,
        with a stable `repr`).

    Returns: what `fn` returns.
    """
    import jax

    folder = _state["folder"]
    leaves = jax.tree.leaves(args)
    if folder is None or jax.config.jax_disable_jit or not _cacheable(fn, tag) or not all(map(_concrete, leaves)):
        return fn(*args, **static)
    key = program_key(fn, args, static, tag)
    compiled = _loaded.get(key)
    if compiled is None and key not in _plain:
        compiled = _load_or_compile(fn, args, static, folder, key)
    if compiled is None:                                    # not storable: plain jit
        return fn(*args, **static)
    return compiled(*leaves)


def prefetch(fn: Callable, *specs, tag=None, **static) -> None:
    """Load (or compile and store) the program `call(fn, *args, **static)` will run for
    arguments of these shapes and dtypes, without running it: from a worker thread, a
    program's load overlaps other work (loading holds no GIL). Nothing when the cache is off.

    Args:
      specs: `jax.ShapeDtypeStruct` (or arrays) standing for the positional arguments.
    """
    folder = _state["folder"]
    if folder is None or not _cacheable(fn, tag):
        return
    key = program_key(fn, specs, static, tag)
    if key not in _loaded and key not in _plain:
        _load_or_compile(fn, specs, static, folder, key)


def _load_or_compile(fn, args, static, folder: Path, key: str):
    """The stored program of `key` (a function of the leaves of `args`), loaded or built and
    stored; None when it cannot be stored (it then runs through plain jit, and a marker file
    says so to later processes)."""
    path, exported, marker = (folder / f"{key}{suffix}" for suffix in (_SUFFIX, _EXPORT_SUFFIX, _PLAIN_SUFFIX))
    if marker.exists():
        _plain.add(key)
        return None
    program = _load(path) if path.exists() else None          # loads run in parallel (no GIL held)
    if program is None and exported.exists():
        program = _load_exported(exported)
    if program is None:
        compiled, fresh = _compile_fresh(fn, args, static)
        if compiled is not None:
            program = compiled
            if fresh and not _store(compiled, folder, key):     # later processes: plain jit,
                _write_marker(marker)                           # through JAX's cache
        else:                                               # custom calls: exported StableHLO
            program, blob = _export(fn, args, static)
            if program is None or not _write(folder, exported.name, blob):
                _plain.add(key)
                _write_marker(marker)
                return None
    _loaded[key] = program
    return program


def _export(fn, args, static):
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
        specs = [jax.ShapeDtypeStruct(np.shape(a), _dtype(a)) for a in leaves]
        exported = export.export(jax.jit(program))(*specs)
        blob = pickle.dumps((bytes(exported.serialize()), out["tree"]), protocol=pickle.HIGHEST_PROTOCOL)
        if not _tree_survives(out["tree"]):
            return None, None
    except Exception:
        return None, None
    return _exported_program(exported, out["tree"]), blob


def _exported_program(exported, tree):
    import jax

    return lambda *leaves: jax.tree.unflatten(tree, exported.call(*leaves))


def _load_exported(path: Path):
    """The exported program at `path`, or None (unreadable or stale: build again)."""
    from jax import export

    return _read(path, lambda payload: _exported_program(export.deserialize(bytearray(payload[0])), payload[1]))


def _write_marker(marker: Path) -> None:
    with contextlib.suppress(OSError):                      # a cache that cannot be written is no error
        marker.touch(mode=0o600)


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

    program.__name__ = program.__qualname__ = f"gfjax_aot_{(_name(fn) or 'program').replace('.', '_')}"
    return program, leaves


def _compile_fresh(fn, args, static):
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

    Returns: `(compiled, fresh)`: `(None, False)` for a program with custom calls; `fresh` is
    False if JAX reports a cache hit all the same (then it is used but not stored).
    """
    import jax

    program, leaves = _leaf_program(fn, args, static)
    lowered = jax.jit(program).lower(*leaves)
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


_hits = threading.local()             # JAX cache hits seen by this thread's compile


def _watch_cache_hits() -> None:
    if _state.get("watching"):
        return
    import jax

    def listen(event: str, **_):
        if event == "/jax/compilation_cache/cache_hits":
            _hits.count = getattr(_hits, "count", 0) + 1

    jax.monitoring.register_event_listener(listen)
    _state["watching"] = True
