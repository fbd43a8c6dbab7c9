"""Jitted programs kept across processes: `jax.export` artifacts in an on-disk cache.

A new `gfjax filter` process pays, per jitted program, tracing (Python), lowering (MLIR) and
loading the compiled executable from JAX's persistent compilation cache. For DMF on an 824 k
point tile tracing and lowering were 0.3 s of a 1.7 s process. `call(fn, *args, **static)`
skips both after the first process: the program `fn(*args, **static)` is exported once
(`jax.export`: StableHLO plus its pytree signature), serialized into `folder`, and later
processes deserialize it and call it, which lowers only a thin wrapper around the stored
module. The compiled executable still comes from JAX's compilation cache.

Off by default (`call` is then `fn(*args, **static)`); `gfjax.cli` turns it on next to the
compilation cache, and `enable(folder)` does so in a notebook or a batch script. This module
imports JAX only when a program is called (`gfjax info` stays fast).

The key of a program: `fn`'s module and name, the static keyword arguments (their `repr`),
each argument's shape and dtype, the JAX version, the backend, the JAX options that change
tracing, and a hash of the gfjax source files, so a change of code never runs a stale
program. Arguments must be concrete (numpy or JAX arrays, numpy scalars): under `jit`,
`vmap` or `grad`, or with Python scalars, `call` is `fn(*args, **static)`. A missing,
unreadable or stale artifact is (re)exported; nothing here raises for a cache problem.
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

__all__ = ["enable", "disable", "enabled_folder", "call", "serializable", "program_key", "MAX_FILES"]

MAX_FILES = 512                 # artifacts kept (least recently used go first); each is ~10-100 kB
_SUFFIX = ".jaxexport"

_state: dict[str, Any] = {"folder": None, "source_hash": None}
_loaded: dict[str, Any] = {}    # key -> jax.export.Exported, for this process
_output_types: list[type] = []
_registered: set[type] = set()
_lock = threading.Lock()        # DMF calls programs from two threads


def enable(folder: str | os.PathLike) -> Path | None:
    """Keep exported programs in `folder` (created if needed). Returns it, or None (and the
    cache stays off) when it cannot be created or `jax.export` cannot serialize (it needs
    the `flatbuffers` package)."""
    folder = Path(folder)
    if importlib.util.find_spec("flatbuffers") is None:     # jax.export's serialization format
        return None
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    _state["folder"] = folder
    return folder


def disable() -> None:
    """Turn the cache off (`call` is then `fn(*args, **static)`)."""
    _state["folder"] = None
    _loaded.clear()


def enabled_folder() -> Path | None:
    """The cache folder, or None when the cache is off."""
    return _state["folder"]


def serializable(cls: type) -> type:
    """Class decorator: a `NamedTuple` that a cached program returns (jax.export serializes
    only the pytree node types it was told about). Returns `cls` unchanged."""
    _output_types.append(cls)
    return cls


def _register_output_types() -> None:
    from jax import export

    for cls in _output_types:
        if cls not in _registered:
            try:
                export.register_namedtuple_serialization(cls, serialized_name=f"{cls.__module__}.{cls.__qualname__}")
            except ValueError:                              # registered by other code already
                pass
            _registered.add(cls)


def _source_hash() -> str:
    """sha256 of every `gfjax/**/*.py` (relative path and bytes), once per process."""
    if _state["source_hash"] is None:
        root = Path(__file__).resolve().parent
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        _state["source_hash"] = digest.hexdigest()
    return _state["source_hash"]


def _concrete(x) -> bool:
    import jax
    import numpy as np

    return isinstance(x, (np.ndarray, np.generic)) or (isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer))


def program_key(fn: Callable, args: tuple, static: dict) -> str:
    """The cache key of `fn(*args, **static)` (hex sha256; see the module docstring)."""
    import jax
    import numpy as np

    signature = [f"{np.shape(a)}:{np.result_type(a)}" for a in args]
    options = {name: getattr(jax.config, name) for name in
               ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_dtype_promotion")}
    parts = [f"{fn.__module__}.{getattr(fn, '__qualname__', fn.__name__)}", repr(sorted(static.items())),
             ";".join(signature), jax.__version__, jax.default_backend(), repr(sorted(options.items())), _source_hash()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _load(path: Path):
    from jax import export

    try:
        exported = export.deserialize(bytearray(path.read_bytes()))
        os.utime(path)                                      # least recently used goes first
        return exported
    except Exception:                                       # unreadable or from another version: re-export
        return None


def _store(exported, folder: Path, key: str) -> None:
    try:
        blob = exported.serialize()
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{key[:16]}.", suffix=".tmp")
        with os.fdopen(fd, "wb") as file:
            file.write(blob)
        os.replace(tmp, folder / f"{key}{_SUFFIX}")         # atomic: readers never see half a file
        _prune(folder)
    except Exception:                                       # a cache that cannot be written is no error
        return


def _prune(folder: Path) -> None:
    files = sorted(folder.glob(f"*{_SUFFIX}"), key=lambda p: p.stat().st_mtime)
    for path in files[:max(0, len(files) - MAX_FILES)]:
        path.unlink(missing_ok=True)


def call(fn: Callable, *args, **static):
    """`fn(*args, **static)`, through the on-disk program cache when it is on.

    Args:
      fn: a `jax.jit`-wrapped function whose keyword arguments `static` are all static
        (hashable; their `repr` enters the key) and whose positional `args` are arrays.
      args: concrete arrays (numpy or JAX) or numpy scalars.

    Returns: what `fn` returns (its output pytree types must be `serializable`).
    """
    import jax

    folder = _state["folder"]
    if folder is None or jax.config.jax_disable_jit or not all(_concrete(a) for a in args):
        return fn(*args, **static)
    key = program_key(fn, args, static)
    exported = _loaded.get(key)
    if exported is None:
        exported = _load_or_export(fn, args, static, folder, key)
    return exported.call(*args)


def _load_or_export(fn, args, static, folder: Path, key: str):
    import jax
    import numpy as np
    from jax import export

    with _lock:
        _register_output_types()
        path = folder / f"{key}{_SUFFIX}"
        exported = _load(path) if path.exists() else None
    if exported is None:
        specs = [jax.ShapeDtypeStruct(np.shape(a), np.result_type(a)) for a in args]
        exported = export.export(fn)(*specs, **static)
        _store(exported, folder, key)
    _loaded[key] = exported
    return exported

