"""Brute-force numpy PMF (Zhang et al. 2003) for small rasters: loops, no cleverness."""
from __future__ import annotations

import numpy as np


def zmin(xy: np.ndarray, z: np.ndarray, shape: tuple[int, int], cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Lowest z per cell (row 0 = north) and the filled mask, by a loop over points."""
    h, w = shape
    out = np.full(shape, np.inf)
    for (x, y), zz in zip(xy.astype(np.float64), z):
        col, row = int(np.floor(x / cell_m)), h - 1 - int(np.floor(y / cell_m))
        if 0 <= row < h and 0 <= col < w:
            out[row, col] = min(out[row, col], zz)
    return out, np.isfinite(out)


def fill_nearest(z: np.ndarray, filled: np.ndarray) -> np.ndarray:
    """Each empty cell takes its nearest filled cell (Euclidean; ties: smallest row-major index)."""
    h, w = z.shape
    src = np.argwhere(filled)
    out = z.copy()
    for r in range(h):
        for c in range(w):
            if not filled[r, c]:
                d2 = (src[:, 0] - r) ** 2 + (src[:, 1] - c) ** 2
                best = np.flatnonzero(d2 == d2.min())
                k = min(best, key=lambda i: src[i, 0] * w + src[i, 1])
                out[r, c] = z[tuple(src[k])]
    return out


def opening(z: np.ndarray, domain: np.ndarray, radius: int) -> np.ndarray:
    """Square opening of side `2 radius + 1` over domain cells only; others keep their value."""
    h, w = z.shape

    def reduce(a: np.ndarray, op, fill: float) -> np.ndarray:
        out = np.empty_like(a)
        for r in range(h):
            for c in range(w):
                win = a[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1]
                dom = domain[max(r - radius, 0):r + radius + 1, max(c - radius, 0):c + radius + 1]
                out[r, c] = op(np.where(dom, win, fill))
        return out

    eroded = reduce(z, np.min, np.inf)
    opened = reduce(eroded, np.max, -np.inf)
    return np.where(domain, opened, z)


def pmf(xy, z, shape, *, windows, thresholds, cell_m=1.0, domain=None) -> tuple[np.ndarray, list[np.ndarray]]:
    """Ground per point and the opened surfaces, Zhang et al. (2003) as PDAL runs it."""
    domain = np.ones(shape, bool) if domain is None else domain
    surface, filled = zmin(xy, z, shape, cell_m)
    surface = fill_nearest(surface, filled & domain)
    h = shape[0]
    rows = h - 1 - np.floor(xy[:, 1] / cell_m).astype(int)
    cols = np.floor(xy[:, 0] / cell_m).astype(int)
    ground = np.ones(len(z), bool)
    surfaces = []
    for size, dh in zip(windows, thresholds):
        surface = opening(surface, domain, (size - 1) // 2)
        surfaces.append(surface)
        ground &= (z - surface[rows, cols]) < dh
    return ground, surfaces
