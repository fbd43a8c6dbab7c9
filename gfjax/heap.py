"""The C heap of a gfjax process: glibc's malloc set for one large window after another.

A filter allocates and frees arrays of a window's points again and again (a survey's window of
4 M points: columns of 32 MB and more). glibc's defaults suit other programs: every thread gets
its own arena, every block over 32 MB is a mapping of its own, and the heap above 128 kB is
given back to the system, so each window faults in fresh zeroed pages again. `tune` sets the
heap of a process that gfjax owns (the `gfjax` program, a local Dask worker); a library call
leaves the process's allocator to its owner. `trim` gives free pages back once, where a large
one-off allocation is over. Other C libraries than glibc are left alone.
"""
from __future__ import annotations

import contextlib
import functools
import os
import sys

__all__ = ["KEEP_FREED_BYTES", "tune", "trim"]

# glibc's mallopt options (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8
KEEP_FREED_BYTES = 1 << 30       # free heap kept at its top for reuse, not given back [bytes]


@functools.cache
def _libc():
    """glibc through ctypes, or None (another system or C library)."""
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL("libc.so.6")
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    return None


def tune() -> None:
    """Set glibc's heap for large windows, before JAX starts its threads; the user's own
    settings win (`MALLOC_ARENA_MAX`, `MALLOC_MMAP_MAX_`, `MALLOC_TRIM_THRESHOLD_`, malloc
    tunables in `GLIBC_TUNABLES`).

    - At most one malloc arena per core. glibc gives every thread that allocates its own arena
      (up to 8 per core) and returns little of a freed arena to the system, so a process that
      filters one large window after another keeps the high-water mark of each thread: DMF
      over a survey of 12 bcts_2 copies (`experiments/survey_scale.py`'s files) peaked at
      1.74 GiB with the default and 0.97 GiB with one arena per core, in about the same time.
    - Freed memory kept for the next window: no block mapped apart, up to `KEEP_FREED_BYTES`
      free at the heap's top. 42 copies of bcts_2 as a SMRF survey took 36.0 s instead of
      40.8 s (system time 3.9 s instead of 9.3 s), peaking at 990 MiB instead of 890 MiB; the
      same files one by one 26.9 s instead of 29.9 s (`farm-bench`, 3 pairs each;
      `experiments/results/survey_scale.md`).
    """
    libc = _libc()
    if libc is None:
        return
    env = os.environ
    theirs = "glibc.malloc." in env.get("GLIBC_TUNABLES", "")
    settings = []
    if "MALLOC_ARENA_MAX" not in env and not theirs:
        settings.append((_M_ARENA_MAX, max(1, os.cpu_count() or 1)))
    if not ({"MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_"} & env.keys()) and not theirs:
        settings += [(_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, KEEP_FREED_BYTES)]
    for option, value in settings:
        libc.mallopt(option, value)


def trim() -> None:
    """Give the heap's free pages back to the system now (glibc's `malloc_trim`; elsewhere
    nothing). It walks the heap: 9-27 ms on a fragmented 0.5 GB one."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
