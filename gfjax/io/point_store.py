"""A file's point records as read, uncompressed on disk: a survey decompresses each file once.

A survey reads every file before it filters any (its catalog, the terrain and estimates of the
whole survey), and writes each file's classified copy afterwards. The catalog's pass keeps
each file's records, exactly as the file holds them (the point format's bytes, every dimension
and extra byte), in a `.npy` of the point format's dtype (`write`); the copy and the file's
`Cloud` are then made from it (`blocks`, `load`; `gfjax.io.stream.open_points(stored=...)`,
`gfjax.io.las.read(stored=...)`), not by decompressing the file again. They are mapped
(`mapped`), not read: nothing is copied out of the page cache.
"""
from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np


class Writer:
    """Records appended to a new store `path` of `n_points` rows of `dtype` (a LAS point format's
    `dtype()`), a chunk at a time, in file order; a context manager."""

    def __init__(self, path: str | os.PathLike, dtype: np.dtype, n_points: int):
        self.path = Path(path)
        header = np.lib.format.open_memmap(self.path, mode="w+", dtype=dtype, shape=(n_points,))
        self._offset = header.offset
        del header
        self._file = open(self.path, "r+b")          # noqa: SIM115 (closed by __exit__)
        self._file.seek(self._offset)

    def append(self, records: np.ndarray) -> None:
        """The next `len(records)` rows (a structured array of the store's dtype)."""
        records.tofile(self._file)

    def __enter__(self) -> Writer:
        return self

    def __exit__(self, *exc) -> None:
        self._file.close()


def _layout(path: str | os.PathLike) -> tuple[np.dtype, int, int]:
    """`(dtype, rows, offset of row 0 [bytes])` of a store, from its header alone."""
    mapped = np.load(path, mmap_mode="r")
    return mapped.dtype, int(mapped.shape[0]), int(mapped.offset)


def blocks(path: str | os.PathLike, size: int) -> Iterator[tuple[int, np.ndarray]]:
    """`(start, records)`: the store's rows `start` to `start + len(records)`, `size` at a time,
    mapped copy-on-write (`mapped`)."""
    dtype, n, offset = _layout(path)
    for start in range(0, n, size):
        count = min(size, n - start)
        yield start, mapped(path, dtype, count, offset + start * dtype.itemsize, writable=True)


def load(path: str | os.PathLike) -> np.ndarray:
    """Every row of a store `(n,)`, mapped copy-on-write (`mapped`)."""
    dtype, n, offset = _layout(path)
    return mapped(path, dtype, n, offset, writable=True)


def mapped(path: str | os.PathLike, dtype: np.dtype, count: int | None = None, offset: int = 0, *,
           writable: bool = False) -> np.ndarray:
    """`count` rows of `dtype` (None: to the file's end) from byte `offset` of the file `path`,
    mapped: read-only, or `writable` copy-on-write (a write changes this array, not the file).
    Nothing is copied out of the page cache, which cost a survey's passes over its stores more
    than their arithmetic (reading 2.8 GB in blocks of 40 MB: 1.1-1.6 s of system time; mapped,
    0.2 s). The mapping lasts as long as the array or a view of it does, and its pages count as
    the process's while they do."""
    if count is None:
        count = (os.path.getsize(path) - offset) // np.dtype(dtype).itemsize
    if count == 0:
        return np.empty(0, dtype)
    return np.memmap(path, dtype=dtype, mode="c" if writable else "r", offset=offset,
                     shape=(count,)).view(np.ndarray)
