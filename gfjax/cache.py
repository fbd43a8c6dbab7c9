"""Where compiled programs are kept between processes, for the command line and the Python API.

Two caches, both under `$XDG_CACHE_HOME/gfjax` (by default `~/.cache/gfjax`): JAX's persistent
compilation cache (`jax/`) and gfjax's own store of compiled programs (`export/`,
`gfjax.aot`). `setup()` turns both on. `import gfjax` leaves JAX's settings and the disk
alone; every `gfjax` command, and the first call of a method's `filter` or `warm` in a process
(`persistent`), turn the caches on, so a notebook restart or a new script loads what an
earlier process compiled. `GFJAX_CACHE=0` turns both off (each process then compiles afresh);
`GFJAX_EXPORT_CACHE` and `JAX_COMPILATION_CACHE_DIR` move one of them elsewhere.

JAX reads its cache folder when it first compiles: a process that compiled with JAX before it
imported gfjax keeps JAX's choice for JAX's cache (gfjax's own store still works).
This module imports JAX only when JAX is already imported (`gfjax info` stays fast).
"""
from __future__ import annotations

import functools
import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path

from gfjax import aot

__all__ = ["SWITCH_ENV", "CACHE_SIZE_BYTES", "setup", "ensure", "persistent", "enable", "folder", "export_folder"]

SWITCH_ENV = "GFJAX_CACHE"   # "0" or "": no persistent caches in this process
CACHE_SIZE_BYTES = 1 << 30   # bound of the persistent JAX compilation cache


def folder() -> Path:
    """JAX's cache: `$XDG_CACHE_HOME/gfjax/jax`, by default `~/.cache/gfjax/jax`."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "gfjax" / "jax"


def export_folder() -> Path | None:
    """gfjax's program store: `$GFJAX_EXPORT_CACHE` if set (empty or "0": none), else
    `gfjax/export` beside `folder()`."""
    setting = os.environ.get("GFJAX_EXPORT_CACHE")
    if setting is None:
        return folder().parent / "export"
    return None if setting in ("", "0") else Path(setting)


def setup() -> Path | None:
    """`enable()` unless `GFJAX_CACHE` is "0" or empty; returns JAX's cache folder in use."""
    if os.environ.get(SWITCH_ENV, "1") in ("", "0"):
        return None
    return enable()


_state = {"set_up": False}


def ensure() -> None:
    """`setup()` once per process (later calls do nothing)."""
    if not _state["set_up"]:
        _state["set_up"] = True
        setup()


def persistent(function: Callable) -> Callable:
    """Decorate a method's `filter` or `warm`: the caches are turned on (`ensure`) before its
    first call in the process, so the API keeps the command line's warm starts without
    `import gfjax` touching JAX's settings or the disk."""
    @functools.wraps(function)
    def call(*args, **kwargs):
        ensure()
        return function(*args, **kwargs)
    return call


def enable() -> Path | None:
    """Turn on JAX's persistent compilation cache in `folder()` (before any compile), and
    gfjax's store of compiled programs (`gfjax.aot`) in `export_folder()`.

    Every compiled program is kept (`min_compile_time_secs = 0`), up to `CACHE_SIZE_BYTES`
    (JAX needs the `filelock` package to enforce that bound; without it the cache is unbounded).
    Settings the user made through `JAX_*` environment variables win.

    JAX's cache holds executables, so its folder obeys `gfjax.aot`'s rule
    (`aot.private_folder`): private to this user (0700), every folder above it writable by no
    one else. A folder named in `JAX_COMPILATION_CACHE_DIR` is checked too (a remote URL is
    left to JAX; an empty one means no cache). A refused folder means no persistent cache for
    this process (one warning line on stderr), and so does an entry in it that another user
    owns, or a symbolic link (`aot.planted_entry`). Returns the local folder in use, or None.
    """
    programs = export_folder()
    if programs is not None:
        aot.enable(programs)
    jax = sys.modules.get("jax")
    user_folder = os.environ.get("JAX_COMPILATION_CACHE_DIR")
    if user_folder == "" or (user_folder and "://" in user_folder):
        return None       # turned off (by the user, or by an earlier refusal), or a remote store (gs://...)
    checked = aot.private_folder(user_folder or folder(), what="persistent compilation cache")
    if checked is None:
        if user_folder:
            _turn_off_jax_cache(jax)
        return None
    planted = aot.planted_entry(checked)
    if planted is not None:
        aot.warn_once(f"{planted}; running without the persistent compilation cache "
                      f"(remove the entry, or the folder, to use it again)")
        _turn_off_jax_cache(jax)
        return None
    settings = {"jax_compilation_cache_dir": str(checked),
                "jax_persistent_cache_min_compile_time_secs": 0.0,
                "jax_persistent_cache_min_entry_size_bytes": 0}
    if importlib.util.find_spec("filelock") is not None:
        settings["jax_compilation_cache_max_size"] = CACHE_SIZE_BYTES
    for key, value in settings.items():
        if key.upper() in os.environ:
            continue
        if jax is not None:
            jax.config.update(key, value)
        else:  # read by JAX when it is first imported
            os.environ[key.upper()] = str(value)
    return checked


def _turn_off_jax_cache(jax) -> None:
    """No persistent compilation cache in this process (JAX reads its folder when first used)."""
    if jax is not None:
        jax.config.update("jax_compilation_cache_dir", None)
    os.environ["JAX_COMPILATION_CACHE_DIR"] = ""     # read by JAX when it is first imported
