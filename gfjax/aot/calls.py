"""Programs called through the store: looked up in this process, loaded, or compiled and stored.

`call(fn, *args, **static)` is `fn(*args, **static)` while the store is off (`enable` turns it
on), under `jit`, `vmap` or `grad` (traced arguments), and for a program the key cannot tell
apart (`gfjax.aot.keys.cacheable`). Otherwise the program is taken from this process, else
loaded from the folder, else compiled (or exported) and stored (`gfjax.aot.build`,
`gfjax.aot.store`). `prefetch`, `prefetching` and `warm_all` prepare programs ahead without
running them (`gfjax warmup`, a worker thread); `on_compile` tells a command a compile is
coming. A program that cannot be stored leaves a marker and runs through plain jit in later
processes.
"""
from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from gfjax import heap
from gfjax.aot import build, store
from gfjax.aot.folder import Refused, open_folder, private_folder, reason, warn_once
from gfjax.aot.keys import cacheable, program_key

__all__ = ["enable", "disable", "release", "enabled_folder", "call", "programs", "prefetch", "prefetching",
           "warm_all", "on_compile"]

_state: dict[str, Any] = {"folder": None}
_loaded: dict[str, Any] = {}    # key -> program of the argument leaves, for this process
_from_disk: set[str] = set()    # keys of `_loaded` programs read from a file
_plain: set[str] = set()        # keys of programs that run through plain jit (custom calls)


def enable(folder: str | os.PathLike) -> Path | None:
    """Keep compiled programs in `folder` (see `private_folder`). Returns the folder (symbolic
    links resolved), or None, with one warning line on stderr, when it is refused: the cache
    then stays off and every program compiles as plain jit."""
    checked = private_folder(folder)
    _state["folder"] = checked
    return checked


def disable() -> None:
    """Turn the cache off (`call` is then `fn(*args, **static)`)."""
    _state["folder"] = None
    _loaded.clear()
    _from_disk.clear()
    _plain.clear()


def release() -> None:
    """Drop the programs this process holds (ours and `jax.jit`'s), so their memory goes back.

    Each compiled XLA CPU program keeps its code mapped, in several memory maps, and a process
    may hold 65,530 maps (`vm.max_map_count`): a job that compiles many shapes one after the
    other (a grid search over a method's static settings: DMF's grid takes 6,000-8,500 maps
    per ISPRS sample) releases them between its parts. The folder stays on; a program needed
    again is read back from it (or from JAX's persistent cache) instead of compiled again.
    """
    import jax

    _loaded.clear()
    _from_disk.clear()
    jax.clear_caches()


def enabled_folder() -> Path | None:
    """The cache folder, or None when the cache is off."""
    return _state["folder"]


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
    if _state.get("prefetching"):
        prefetch(fn, *args, tag=tag, **static)
        return jax.eval_shape(lambda *a: fn(*a, **static), *args)
    leaves = jax.tree.leaves(args)
    if folder is None or jax.config.jax_disable_jit or not cacheable(fn, tag) or not all(map(_concrete, leaves)):
        return fn(*args, **static)
    key = program_key(fn, args, static, tag)
    compiled = _loaded.get(key)
    if compiled is None and key not in _plain:
        compiled = _load_or_compile(fn, args, static, folder, key, _module(fn, tag))
    if compiled is None:                                    # not storable, or refused: plain jit
        return fn(*args, **static)
    if key not in _from_disk:
        return compiled(*leaves)
    try:
        return compiled(*leaves)
    except Exception:             # a stored program that does not fit its caller: plain jit,
        _forget(folder, key)      # and the next call compiles and stores it again
        return fn(*args, **static)


def programs(package: str, stages: Sequence[tuple[str, Callable, Any]], *, key: tuple,
             batched: bool) -> tuple[Callable, ...]:
    """A method's stages as programs: each `(name, fn, in_axes)` of `stages` becomes
    `jax.jit(fn)` (of `jax.vmap(fn, in_axes)` when `batched`: a batch of tiles) called through
    `call`, tagged `(f"{package}.{name}", *key, batched)`. `key` holds what `fn` binds (its
    static config, the raster shape), so the tag names one program. Each stage compiles apart:
    a costly raster stage compiles once per raster shape, a cheap point stage again for each
    point capacity."""
    import jax

    out = []
    for name, fn, in_axes in stages:
        program = jax.jit(jax.vmap(fn, in_axes=in_axes) if batched else fn)
        out.append(functools.partial(call, program, tag=(f"{package}.{name}", *key, batched)))
    return tuple(out)


def prefetch(fn: Callable, *specs, tag=None, **static) -> None:
    """Load (or compile and store) the program `call(fn, *args, **static)` will run for
    arguments of these shapes and dtypes, without running it: from a worker thread, a
    program's load overlaps other work (loading holds no GIL). Nothing when the cache is off.

    Args:
      specs: `jax.ShapeDtypeStruct` (or arrays) standing for the positional arguments.
    """
    folder = _state["folder"]
    if folder is None or not cacheable(fn, tag):
        return
    key = program_key(fn, specs, static, tag)
    program = _loaded.get(key)
    if program is None and key not in _plain:
        program = _load_or_compile(fn, specs, static, folder, key, _module(fn, tag))
    if hasattr(program, "compile"):       # exported: its executable lives in JAX's cache
        import jax

        program.compile(*jax.tree.leaves(specs))


@contextlib.contextmanager
def prefetching():
    """Within this context `call` runs nothing: it loads (or compiles and stores) the program
    and returns the shapes and dtypes of its result (`jax.ShapeDtypeStruct`s), so a driver
    called with `jax.ShapeDtypeStruct` inputs prepares every program a real call of those
    shapes would run (`gfjax warmup`). Nothing is stored when the cache is off."""
    before = _state.get("prefetching", False)
    _state["prefetching"] = True
    try:
        yield
    finally:
        _state["prefetching"] = before


def warm_all(jobs: Sequence[Callable[[], Any]], *, progress: bool = False, desc: str = "programs") -> int:
    """Run `jobs` (each prepares one program: `prefetch`, or a driver under `prefetching`) in
    turn, with a progress bar over them when `progress`. One at a time: XLA already compiles a
    program on every core (two at once took as long on 2 cores). Returns `len(jobs)` (a
    method's `warm`, `gfjax warmup`)."""
    if progress:
        from tqdm.auto import tqdm
        jobs = tqdm(jobs, desc=desc, unit="program")
    with prefetching():
        for job in jobs:
            job()
    return len(jobs)


def on_compile(callback: Callable[[str], None] | None) -> None:
    """Call `callback(module)` just before a program is compiled rather than loaded (`module`:
    the compiled function's module, e.g. `gfjax.smrf.stages`), so a command can say that it is
    compiling instead of sitting silent; None: no calls."""
    _state["on_compile"] = callback


def _concrete(x) -> bool:
    import jax
    import numpy as np

    return isinstance(x, (np.ndarray, np.generic)) or (isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer))


def _module(fn, tag) -> str:
    """The module a program belongs to, for `on_compile`: a tag's leading dotted name (e.g.
    "gfjax.smrf.rasterize_min" -> "gfjax.smrf"; a tagged program is often a partial, whose own
    module is functools'), else `fn`'s module."""
    head = tag[0] if isinstance(tag, tuple) and tag else tag
    if isinstance(head, str) and head.startswith("gfjax."):
        return head.rsplit(".", 1)[0]
    return getattr(fn, "__module__", None) or "gfjax"


def _forget(folder: Path, key: str) -> None:
    """Drop the program of `key` from this process and its entries from the folder."""
    _loaded.pop(key, None)
    _from_disk.discard(key)
    try:
        dir_fd = open_folder(folder)
    except (Refused, OSError):
        return
    try:
        for suffix in (store.SUFFIX, store.EXPORT_SUFFIX):
            with contextlib.suppress(OSError):
                os.unlink(f"{key}{suffix}", dir_fd=dir_fd)
    finally:
        os.close(dir_fd)


def _load_or_compile(fn, args, static, folder: Path, key: str, module: str):
    """The stored program of `key` (a function of the leaves of `args`), loaded or built and
    stored; None when it runs through plain jit: it cannot be stored (a marker file then says
    so to later processes), or the folder is refused now (one warning line)."""
    try:
        dir_fd = open_folder(folder)
    except (Refused, OSError) as err:
        warn_once(f"{reason(err, folder)}; compiling without the program cache")
        return None
    try:
        return _load_or_compile_in(fn, args, static, dir_fd, key, module)
    finally:
        os.close(dir_fd)


def _load_or_compile_in(fn, args, static, dir_fd: int, key: str, module: str):
    name, exported, marker = (f"{key}{suffix}" for suffix in (store.SUFFIX, store.EXPORT_SUFFIX, store.PLAIN_SUFFIX))
    if store.marker_present(dir_fd, marker):
        _plain.add(key)
        return None
    program = store.load(dir_fd, name, key)                 # loads run in parallel (no GIL held)
    if program is None:
        program = store.load_exported(dir_fd, exported, key)
    if program is not None:
        _from_disk.add(key)
    else:
        if _state.get("on_compile") is not None:
            _state["on_compile"](module)
        compiled, fresh = build.compile_fresh(fn, args, static)
        heap.trim()                                         # the compiler's scratch, freed now
        if compiled is not None:
            program = compiled
            if fresh:                                       # else JAX's cache gave it: not stored
                blob = store.serialize(compiled)
                if blob is None:                            # later processes: plain jit,
                    store.write_marker(dir_fd, marker)      # through JAX's cache
                else:
                    store.write(dir_fd, name, store.wrap(key, blob))   # disk full: stored next time
        else:                                               # custom calls: exported StableHLO
            program, blob = build.export_program(fn, args, static)
            if program is None:
                _plain.add(key)
                store.write_marker(dir_fd, marker)
                return None
            store.write(dir_fd, exported, store.wrap(key, blob))
    _loaded[key] = program
    return program
