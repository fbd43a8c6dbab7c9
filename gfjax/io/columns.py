"""Reductions over the rows of a few-column array `(n, k)`, one column at a time, and the
slices of rows a host step reads a window's millions of points in.

numpy reduces `(n, 3)` coordinates along axis 0, or `(n, 2)` flags along axis 1, through an
inner loop of k elements: on 531,662 points, `xyz.min(axis=0)` takes 11 ms and
`np.all(flags, axis=1)` 9 ms, against 0.5 ms and 0.3 ms column by column. Tiling, indexing and
grouping a survey run such reductions on every window, so they go through here.
"""
from __future__ import annotations

import numpy as np

__all__ = ["SLICE_ROWS", "slices", "lows", "highs", "every", "some"]

# Rows a host step over a survey's window (millions of points) reads at a time, so its
# temporaries are a few columns of a slice, not of the window (memory, never results).
SLICE_ROWS = 1 << 18


def slices(n: int) -> list[slice]:
    """`slice`s of `SLICE_ROWS` rows, in order, covering rows `0..n`."""
    return [slice(start, min(start + SLICE_ROWS, n)) for start in range(0, n, SLICE_ROWS)]


def lows(a: np.ndarray) -> np.ndarray:
    """Minimum of each column of `(n, k)`, n >= 1: `(k,)` (= `a.min(axis=0)`)."""
    return np.array([a[:, j].min() for j in range(a.shape[1])], dtype=a.dtype)


def highs(a: np.ndarray) -> np.ndarray:
    """Maximum of each column of `(n, k)`, n >= 1: `(k,)` (= `a.max(axis=0)`)."""
    return np.array([a[:, j].max() for j in range(a.shape[1])], dtype=a.dtype)


def every(flags: np.ndarray) -> np.ndarray:
    """Rows of bool `(n, k)` true in every column: `(n,)` (= `np.all(flags, axis=1)`)."""
    out = flags[:, 0].copy()
    for j in range(1, flags.shape[1]):
        out &= flags[:, j]
    return out


def some(flags: np.ndarray) -> np.ndarray:
    """Rows of bool `(n, k)` true in some column: `(n,)` (= `np.any(flags, axis=1)`)."""
    out = flags[:, 0].copy()
    for j in range(1, flags.shape[1]):
        out |= flags[:, j]
    return out
