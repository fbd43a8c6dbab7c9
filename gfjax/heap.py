"""The C heap of a gfjax process: glibc's malloc set for one large window after another.

A filter allocates and frees arrays of a window's points again and again (a survey's window of
4 M points: columns of 32 MB and more). glibc's defaults suit other programs: every thread gets
its own arena, and the heap's free top is given back to the system as soon as it passes a few
megabytes, so each window faults in fresh zeroed pages again. `tune` sets the
heap of a process that gfjax owns (the `gfjax` program, a local Dask worker); a library call
leaves the process's allocator to its owner. `trim` gives free pages back once, where a large
one-off allocation is over. Other C libraries than glibc are left alone.

`tune` also stops numpy from asking the kernel for huge pages (below).
"""
from __future__ import annotations

import contextlib
import functools
import importlib
import os
import sys

__all__ = ["KEEP_FREED_BYTES", "MAPPED_APART_BYTES", "tune", "trim"]

# glibc's mallopt options (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8
KEEP_FREED_BYTES = 1 << 30       # free heap kept at its top for reuse, not given back [bytes]
MAPPED_APART_BYTES = 32 << 20    # blocks this large or larger are mappings of their own [bytes]


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
    """Set glibc's heap, and numpy's huge pages, for large windows, before JAX starts its
    threads; the user's own settings win (`MALLOC_ARENA_MAX`, `MALLOC_MMAP_THRESHOLD_`,
    `MALLOC_TRIM_THRESHOLD_`, malloc tunables in `GLIBC_TUNABLES`, `NUMPY_MADVISE_HUGEPAGE`).

    - At most one malloc arena per core. glibc gives every thread that allocates its own arena
      (up to 8 per core) and returns little of a freed arena to the system, so a process that
      filters one large window after another keeps the high-water mark of each thread: DMF
      over a survey of 12 bcts_2 copies (`experiments/survey_scale.py`'s files) peaked at
      1.74 GiB with the default and 0.97 GiB with one arena per core, in about the same time.
    - Freed memory kept for the next window: blocks below `MAPPED_APART_BYTES` from the heap
      from the start (glibc's own threshold starts at 128 kB and slides up to that as blocks
      are freed), and up to `KEEP_FREED_BYTES` free at its top kept (by default at most twice
      the threshold). 16 copies of bcts_2 as a SMRF survey took 0.946 of the time (14.1 s
      against 14.7 s, peak 818 MiB against 807 MiB); SparseGF on one of them the same time at
      the same peak (`farm-bench`, 5 pairs each). Larger blocks from the heap too gained more
      on surveys at more memory: a 128 MB threshold 0.95 of the time again at 6 % more peak,
      none at all (every block from the heap) 0.93 at 6 % more on the survey and 23 % more
      on SparseGF.
    - No huge pages asked for by numpy (unless the user's `NUMPY_MADVISE_HUGEPAGE` says). numpy
      marks every array of 4 MB or more for huge pages, and the kernel, by default, compacts
      memory on the spot to find them for such arrays: a survey's windows of millions of points
      then spent more time in the kernel than the pages saved. 16 copies of bcts_2 as a SMRF
      survey took 0.959 of the time without them (27.9 s against 28.9 s, system time 4.7 s
      against 6.0 s, the same peak; `farm-bench`, 4 pairs; 0.937 in 4 pairs without the
      settings above, each in favour), the same files one at a time 1.05 (within the runs'
      spread: their arrays are a quarter as large).
    """
    env = os.environ
    if "NUMPY_MADVISE_HUGEPAGE" not in env:
        setter = _numpy_huge_pages()
        if setter is not None:
            setter(False)
    libc = _libc()
    if libc is None:
        return
    theirs = "glibc.malloc." in env.get("GLIBC_TUNABLES", "")
    settings = []
    if "MALLOC_ARENA_MAX" not in env and not theirs:
        settings.append((_M_ARENA_MAX, max(1, os.cpu_count() or 1)))
    if not ({"MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"} & env.keys()) and not theirs:
        settings += [(_M_MMAP_THRESHOLD, MAPPED_APART_BYTES), (_M_TRIM_THRESHOLD, KEEP_FREED_BYTES)]
    for option, value in settings:
        libc.mallopt(option, value)


def _numpy_huge_pages():
    """numpy's switch of huge pages for its arrays (`_set_madvise_hugepage(on) -> was_on`), or
    None where this numpy has none."""
    for module in ("numpy._core.multiarray", "numpy.core.multiarray"):
        with contextlib.suppress(ImportError, AttributeError):
            return importlib.import_module(module)._set_madvise_hugepage
    return None


def trim() -> None:
    """Give the heap's free pages back to the system now (glibc's `malloc_trim`; elsewhere
    nothing). It walks the heap: 9-27 ms on a fragmented 0.5 GB one."""
    libc = _libc()
    if libc is not None:
        libc.malloc_trim(0)
