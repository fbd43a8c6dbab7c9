"""Brute-force numpy / scipy references for the raster kernels (test-only; others may import).

Everything here is deliberately simple: loops and direct formulas whose correctness is plain
to read, used to check the fast JAX kernels of `gfjax.raster`.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp
import scipy.sparse.linalg as spla


@dataclasses.dataclass(frozen=True)
class Case:
    """A raster test case: a name, a shape, a radius and the share of valid cells."""

    name: str
    shape: tuple[int, int]
    radius: int = 2
    valid_fraction: float = 0.7

    def __str__(self) -> str:
        return f"{self.name}-{self.shape[0]}x{self.shape[1]}-r{self.radius}"


def random_raster(case: Case, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Float32 elevations with ties (rounded to 0.25 m) and a random valid mask."""
    rng = np.random.default_rng(seed)
    z = (np.round(rng.normal(100.0, 5.0, size=case.shape) * 4) / 4).astype(np.float32)
    valid = rng.random(case.shape) < case.valid_fraction
    return z, valid


def disk(radius: int) -> np.ndarray:
    """Disk footprint by its definition: `dx^2 + dy^2 <= r^2` (skimage.morphology.disk)."""
    d = np.arange(-radius, radius + 1)
    return d[:, None] ** 2 + d[None, :] ** 2 <= radius**2


def footprint(kind: str, radius: int) -> np.ndarray:
    return disk(radius) if kind == "disk" else np.ones((2 * radius + 1,) * 2, bool)


def erosion(z, valid, kind, radius):
    """scipy grey erosion with invalid cells and the border at +inf."""
    zi = np.where(valid, z, np.inf) if valid is not None else z
    return ndi.grey_erosion(zi, footprint=footprint(kind, radius), mode="constant", cval=np.inf)


def dilation(z, valid, kind, radius):
    """scipy grey dilation with invalid cells and the border at -inf."""
    zi = np.where(valid, z, -np.inf) if valid is not None else z
    return ndi.grey_dilation(zi, footprint=footprint(kind, radius), mode="constant", cval=-np.inf)


def opening(z, valid, kind, radius):
    return dilation(erosion(z, valid, kind, radius), valid, kind, radius)


def closing(z, valid, kind, radius):
    return erosion(dilation(z, valid, kind, radius), valid, kind, radius)


def canonical_labels(labels: np.ndarray) -> np.ndarray:
    """Relabel ids 1..n by first occurrence (row-major), 0 stays 0: compares partitions."""
    flat = np.asarray(labels).ravel()
    out = np.zeros_like(flat, dtype=np.int64)
    seen: dict[int, int] = {}
    for i, v in enumerate(flat):
        if v != 0:
            out[i] = seen.setdefault(int(v), len(seen) + 1)
    return out.reshape(np.shape(labels))


def structure(connectivity: int) -> np.ndarray:
    return ndi.generate_binary_structure(2, 1 if connectivity == 4 else 2)


def nearest_index(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Brute force: for each cell the row-major index of the nearest valid cell (ties ->
    smallest index) and the squared distance; -1 / 2**30 where nothing is valid."""
    h, w = valid.shape
    src = np.flatnonzero(valid.ravel())
    index = np.full((h, w), -1, np.int64)
    dist2 = np.full((h, w), 1 << 30, np.int64)
    if src.size == 0:
        return index, dist2
    sr, sc = np.divmod(src, w)
    for r in range(h):
        for c in range(w):
            d2 = (sr - r) ** 2 + (sc - c) ** 2
            k = np.argmin(d2)                                # first minimum = smallest index
            index[r, c], dist2[r, c] = src[k], d2[k]
    return index, dist2


def harmonic(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Direct sparse solve of the 4-neighbour Laplace equation on ~valid cells, valid cells
    as Dirichlet data, zero flux across the border (float64)."""
    h, w = z.shape
    free = np.flatnonzero(~valid.ravel())
    out = np.where(valid, z, 0.0).astype(np.float64)
    if free.size == 0 or not valid.any():
        return np.where(valid, z, 0.0).astype(np.float64)
    pos = -np.ones(h * w, np.int64)
    pos[free] = np.arange(free.size)
    rows, cols, vals = [], [], []
    rhs = np.zeros(free.size)
    zf = out.ravel()
    for k, i in enumerate(free):
        r, c = divmod(i, w)
        for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
            if 0 <= rr < h and 0 <= cc < w:
                j = rr * w + cc
                rows.append(k), cols.append(k), vals.append(1.0)
                if pos[j] >= 0:
                    rows.append(k), cols.append(pos[j]), vals.append(-1.0)
                else:
                    rhs[k] += zf[j]
    a = sp.csr_matrix((vals, (rows, cols)), shape=(free.size, free.size))
    flat = out.ravel()
    flat[free] = spla.spsolve(a.tocsc(), rhs)
    return flat.reshape(h, w)


def ring_stats(labels: np.ndarray, values: np.ndarray, valid: np.ndarray, connectivity: int, num_labels: int):
    """Per-label ring (dilation minus region, inside the raster) count, valid count, min, max,
    mean of `values` over valid ring cells, by explicit dilation of each label."""
    k = num_labels + 1
    count = np.zeros(k, np.int64)
    vcount = np.zeros(k, np.int64)
    vmin = np.full(k, np.inf)
    vmax = np.full(k, -np.inf)
    mean = np.zeros(k)
    for lab in range(1, k):
        region = labels == lab
        ring = ndi.binary_dilation(region, structure(connectivity)) & ~region
        count[lab] = ring.sum()
        sel = ring & valid
        vcount[lab] = sel.sum()
        if sel.any():
            vmin[lab], vmax[lab], mean[lab] = values[sel].min(), values[sel].max(), values[sel].astype(np.float64).mean()
    return count, vcount, vmin, vmax, mean


def rasterize(xy: np.ndarray, z: np.ndarray, valid: np.ndarray, cell_m: float, shape: tuple[int, int]) -> dict:
    """Per-cell min/max/mean/count/argmin by a Python loop over the points (row 0 = north)."""
    h, w = shape
    zmin = np.full(shape, np.inf, np.float32)
    zmax = np.full(shape, -np.inf, np.float32)
    total = np.zeros(shape, np.float64)
    count = np.zeros(shape, np.int64)
    argmin = np.full(shape, -1, np.int64)
    for i in range(len(z)):
        col, fy = np.floor(xy[i, 0] / cell_m), np.floor(xy[i, 1] / cell_m)
        if not (valid[i] and np.isfinite(z[i]) and 0 <= col < w and 0 <= fy < h):
            continue
        r, c = int(h - 1 - fy), int(col)
        if z[i] < zmin[r, c]:
            zmin[r, c], argmin[r, c] = z[i], i
        zmax[r, c] = max(zmax[r, c], z[i])
        total[r, c] += z[i]
        count[r, c] += 1
    mean = np.where(count > 0, total / np.maximum(count, 1), 0.0)
    return dict(z_min=zmin, z_max=zmax, z_mean=mean, count=count, argmin=argmin, valid=count > 0)


def bilinear(z: np.ndarray, xy: np.ndarray, cell_m: float) -> np.ndarray:
    """Bilinear between cell centres, clamped, via scipy.ndimage.map_coordinates(order=1)."""
    h, w = z.shape
    col = np.clip(xy[:, 0] / cell_m - 0.5, 0, w - 1)
    row = np.clip(h - 0.5 - xy[:, 1] / cell_m, 0, h - 1)
    return ndi.map_coordinates(z.astype(np.float64), [row, col], order=1, mode="nearest")
