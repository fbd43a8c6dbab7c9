"""What names a stored program: its key, and which programs a key can tell apart.

The key of a program: `fn`'s module and name (or its `tag`), the static keyword arguments (their
`repr`), the pytree structure and each argument's shape, dtype, weak type and placement, the JAX
options that change tracing, and a fingerprint of where it runs: the JAX and jaxlib versions,
the backend and device kind, the host CPU (machine and instruction-set flags: an executable is
machine code), `XLA_FLAGS`, and a hash of the gfjax source files, so a change of gfjax code,
JAX, jaxlib or machine never runs a stale program. Only module-level gfjax functions are cached
by name; a closure or `functools.partial` needs a `tag` naming all it binds (gfjax's callers
give one), and anything else takes plain jit (`cacheable`).
"""
from __future__ import annotations

import hashlib
import importlib.util
import os
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["program_key", "cacheable", "name_of", "dtype_of"]

_state: dict[str, Any] = {"fingerprint": None}   # computed once per process
_REPRS: dict[int, tuple[Any, str]] = {}          # id -> (value kept alive, its repr)
_MAX_REPRS = 64


def program_key(fn: Callable, args: tuple, static: dict, tag=None) -> str:
    """The cache key of `fn(*args, **static)` (hex sha256; see the module docstring). `tag`,
    when given, names the program instead of `fn`'s module and name."""
    import jax
    import numpy as np

    leaves, treedef = jax.tree.flatten(args)
    signature = [f"{np.shape(a)}:{dtype_of(a)}:{'weak' if getattr(a, 'weak_type', False) else ''}:{_placement(a)}"
                 for a in leaves]
    name = repr(tag) if tag is not None else f"{fn.__module__}.{name_of(fn)}"
    parts = [name, _static_repr(static), str(treedef), ";".join(signature), _trace_options(), _fingerprint()]
    if donated(fn):
        parts.append(f"donate {donated(fn)}")
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def donated(fn) -> tuple[int, ...]:
    """The positional arguments `fn`'s `jax.jit` donates (`donate_argnums`), or `()`."""
    info = getattr(fn, "_jit_info", None)
    return tuple(sorted(getattr(info, "donate_argnums", None) or ()))


def donated_leaves(fn, args: tuple) -> tuple[int, ...]:
    """The indices, among the leaves of `args`, of the leaves of the arguments `fn` donates."""
    import jax

    chosen, out, start = set(donated(fn)), [], 0
    for i, arg in enumerate(args):
        count = len(jax.tree.leaves(arg))
        if i in chosen:
            out.extend(range(start, start + count))
        start += count
    return tuple(out)


def cacheable(fn, tag) -> bool:
    """A program the key can tell apart: tagged, or a module-level gfjax function (its code is
    in the fingerprint). Closures, partials and functions from elsewhere take plain jit."""
    if tag is not None:
        return True
    name, module = name_of(fn), getattr(fn, "__module__", None) or ""
    return bool(name) and "<locals>" not in name and (module == "gfjax" or module.startswith("gfjax."))


def name_of(fn) -> str | None:
    """`fn`'s qualified name, or its name, or None."""
    return getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None)


def dtype_of(x):
    """The numpy dtype of an array, a `jax.ShapeDtypeStruct` or a scalar."""
    import numpy as np

    return np.dtype(x.dtype) if hasattr(x, "dtype") else np.result_type(x)


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

        root = Path(__file__).resolve().parents[1]          # gfjax/, this file is gfjax/aot/keys.py
        digest = hashlib.sha256()
        for path in sorted(root.rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode() + b"\0" + path.read_bytes() + b"\0")
        device = jax.devices()[0]
        # the device's client is the backend `jax.extend.backend.get_backend()` returns, without
        # importing `jax.extend` (and Pallas with it: 12 ms of every process)
        platform_version = getattr(getattr(device, "client", None), "platform_version", "")
        for part in (jax.__version__, jaxlib.__version__, device.platform, device.device_kind,
                     platform_version, platform.machine(), _cpu_flags(),
                     os.environ.get("XLA_FLAGS", ""), importlib.util.find_spec("flatbuffers") is not None):
            digest.update(str(part).encode() + b"\0")
        _state["fingerprint"] = digest.hexdigest()
    return _state["fingerprint"]


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


def _static_repr(static: dict) -> str:
    """`repr` of the sorted static arguments; the repr of each value is remembered by identity
    (a network's skeleton takes 80 ms to print, and a caller passes the same one per call)."""
    parts = []
    for name, value in sorted(static.items()):
        known = _REPRS.get(id(value))
        if known is None or known[0] is not value:
            if len(_REPRS) >= _MAX_REPRS:
                _REPRS.clear()
            known = _REPRS[id(value)] = (value, repr(value))
        parts.append(f"({name!r}, {known[1]})")
    return "[" + ", ".join(parts) + "]"


def _placement(a) -> str:
    """The sharding of an argument committed elsewhere than the default device; "" for one on
    it, committed or not (the same program runs both: an output of an exported program is
    committed, the spec `prefetch` gets for it is not)."""
    import jax

    if not (isinstance(a, jax.Array) and a.committed):
        return ""
    devices = a.sharding.device_set
    return "" if len(devices) == 1 and next(iter(devices)) == jax.devices()[0] else repr(a.sharding)
