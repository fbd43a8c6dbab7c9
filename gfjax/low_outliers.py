"""Low outliers: returns far below the terrain (multipath, a beam reflected on its way back), told
before a filter runs so that its surfaces never rest on them.

A filter that builds its surface from below (CSF's inverted cloth, PMF's and DMF's openings) is
pinned on a point 30 m below the terrain: the cloth hangs down to it, the opening spreads it
over its window, and the ground around it reads as objects. Such a point has next to nothing
at its height around it: the terrain around is far above it, whether bare or under canopy.
Real low ground has company: a ditch or a canal bank holds many points along it, a ground
point seen through a canopy gap has the ground points of the other gaps around it, and a
steep slope has half of its neighbours lower than any of its points.

So on the minimum surface (the lowest used return of each cell of about the last-return
spacing), a cell is a low outlier when, of the occupied cells within `RADIUS_CELLS` of it,
fewer than `MIN_COMPANY` lie below the cone `z + THRESHOLD_M + SLOPE * d` over it (`d`: the
horizontal distance between the cells' centres) and at least `MIN_ABOVE` lie above it. The
lowest point of such a cell is a low outlier; the cells are made again without it, and the
test repeats (`MAX_PASSES`), so a few outliers in one cell go one by one and a cluster spread
over up to `MIN_COMPANY - 1` cells goes at once.

Host code (numpy), one shifted comparison per cell of a disk, on a raster of the cloud's
cells: about a tenth of a second a pass on a million cells. `detect` is pure: points in,
flags out. Used by `gfjax.adaptive` before a method whose values follow the data (`hide`).
"""
from __future__ import annotations

import math

import numpy as np

from gfjax.io import columns

__all__ = ["detect", "cell_m", "MIN_CELL_M", "RADIUS_CELLS", "THRESHOLD_M", "SLOPE", "MIN_COMPANY", "MIN_ABOVE",
           "MAX_PASSES"]

# The constants, and why (checked on the training files of `experiments.common.LABELLED`:
# `experiments/low_outliers.py`, `experiments/results/low_outliers.md`).
MIN_CELL_M = 1.0         # the cell: the last returns' spacing (about one ground return a cell where
                         # the ground is bare), at least this [m]: finer cells only split a point's company
RADIUS_CELLS = 4         # the neighbourhood: a disk of 4 cells (49 cells), several last-return spacings,
                         # so under canopy it still holds the ground seen through the other gaps
THRESHOLD_M = 2.0        # company: a cell less than this above the point [m] ...
SLOPE = 1.5              # ... plus this rise over run to it [-]: terrain up to 56° steep keeps its own
                         # lower cells inside the cone, so no slope is taken for an outlier
MIN_COMPANY = 6          # fewer cells than this in the cone: alone (a cluster of 5 outliers still is)
MIN_ABOVE = 12           # and at least this many cells above the cone: the terrain is there and far
                         # above (a point at the edge of the data or between empty water cells is kept)
MAX_PASSES = 8           # outliers stacked in one cell go one a pass: 8 of them at most
_DENSE_CELLS_PER_POINT = 8   # a raster of the box up to this many cells a point; beyond, the occupied cells


def cell_m(last_spacing_m: float) -> float:
    """The cell [m] of the minimum surface: the last returns' spacing, at least `MIN_CELL_M`."""
    return max(MIN_CELL_M, float(last_spacing_m)) if math.isfinite(last_spacing_m) else MIN_CELL_M


def _disk() -> list[tuple[int, int, float]]:
    """The offsets `(drow, dcol, distance in cells)` of the disk of `RADIUS_CELLS`, centre left out."""
    r = RADIUS_CELLS
    return [(dr, dc, math.hypot(dr, dc)) for dr in range(-r, r + 1) for dc in range(-r, r + 1)
            if 0 < dr * dr + dc * dc <= r * r]


def _alone(z_min: np.ndarray, cell: float) -> np.ndarray:
    """Cells `(h, w)` of the minimum surface (+inf where empty) that are low outliers (the
    module docstring)."""
    r = RADIUS_CELLS
    h, w = z_min.shape
    padded = np.pad(z_min, r, constant_values=np.inf)
    company = np.zeros((h, w), np.int32)
    above = np.zeros((h, w), np.int32)
    for dr, dc, d in _disk():
        other = padded[r + dr:r + dr + h, r + dc:r + dc + w]
        cone = z_min + (THRESHOLD_M + SLOPE * d * cell)
        inside = other < cone
        company += inside
        above += np.isfinite(other) & ~inside
    return np.isfinite(z_min) & (company < MIN_COMPANY) & (above >= MIN_ABOVE)


def detect(xyz_m: np.ndarray, used: np.ndarray, *, last_spacing_m: float,
           origin_m: np.ndarray | None = None) -> np.ndarray:
    """The low outliers among the used points (the module docstring).

    Args:
      xyz_m: coordinates, float `(n, 3)` [m].
      used: bool `(n,)`, the returns that count (noise and withheld points left out).
      last_spacing_m: the last returns' spacing [m] (`gfjax.adaptive.Terrain.last_spacing_m`):
        sets the cell (`cell_m`).
      origin_m: the corner the cells are laid from, float `(2,)` or `(3,)` [m] (a survey's frame,
        so a window and the whole survey share cells); None: the used points' minimum.

    Returns:
      bool `(n,)`: True for a low outlier (always a used point).
    """
    used = np.asarray(used, dtype=bool)
    low = np.zeros(used.shape, dtype=bool)
    count = int(np.count_nonzero(used))
    if count == 0:
        return low
    xyz_m = np.asarray(xyz_m, dtype=np.float64)
    cell = cell_m(last_spacing_m)
    lows = [float(xyz_m[:, j].min(where=used, initial=np.inf)) for j in range(2)]
    highs = [float(xyz_m[:, j].max(where=used, initial=-np.inf)) for j in range(2)]
    corner = lows if origin_m is None else np.asarray(origin_m, np.float64)[:2]
    # the cells of the lowest and highest points: floor((v - corner) / cell) never decreases with v
    first, last = ([math.floor((v - c) / cell) for v, c in zip(ends, corner)] for ends in (lows, highs))
    width = last[0] - first[0] + 1
    shape = (last[1] - first[1] + 1, width)

    def keys(rows) -> np.ndarray:
        """Flat cell keys int64 `(k,)` of the points `rows`, from the used points' first cell."""
        key = None
        for j in (1, 0):
            scaled = np.subtract(xyz_m[rows, j], corner[j])
            scaled /= cell
            along = np.floor(scaled, out=scaled).astype(np.int64)
            along -= first[j]
            if key is None:
                key = along
                key *= width
            else:
                key += along
            del scaled
        return key

    dense = shape[0] * shape[1] <= _DENSE_CELLS_PER_POINT * count + 4096
    if dense:
        # the first pass a slice of points at a time, without sorting them: most clouds have no
        # low outlier at all, and a survey's window holds millions of points
        z_min = np.full(shape[0] * shape[1], np.inf)
        for part in columns.slices(len(used)):
            rows = np.flatnonzero(used[part]) + part.start
            np.minimum.at(z_min, keys(rows), xyz_m[rows, 2])
        if not _alone(z_min.reshape(shape), cell).any():
            return low
    index = np.flatnonzero(used)
    key = keys(index)
    z = xyz_m[index, 2]
    # points sorted by cell, then height: a cell's lowest remaining point is its first not flagged
    order = np.lexsort((z, key))
    flagged = np.zeros(index.size, dtype=bool)
    for _ in range(MAX_PASSES):
        alive = order[~flagged[order]]
        keys = key[alive]
        lowest = alive[np.r_[True, keys[1:] != keys[:-1]]]
        cells = key[lowest]
        if dense:
            z_min = np.full(shape[0] * shape[1], np.inf)
            z_min[cells] = z[lowest]
            alone = _alone(z_min.reshape(shape), cell).reshape(-1)[cells]
        else:
            alone = _alone_sparse(cells, z[lowest], width, cell)
        if not alone.any():
            break
        flagged[lowest[alone]] = True
    low[index[flagged]] = True
    return low


def _alone_sparse(cells: np.ndarray, z_min: np.ndarray, width: int, cell: float) -> np.ndarray:
    """`_alone` on the occupied cells only: sorted flat keys `(m,)` of a grid `width` cells wide
    and their lowest heights `(m,)`; for a box the points leave mostly empty (a stray point
    kilometres away adds one cell, not a raster)."""
    company = np.zeros(cells.size, np.int32)
    above = np.zeros(cells.size, np.int32)
    col = cells % width
    for dr, dc, d in _disk():
        near = cells + dr * width + dc
        at = np.minimum(np.searchsorted(cells, near), cells.size - 1)
        there = (cells[at] == near) & (col + dc >= 0) & (col + dc < width)
        inside = there & (z_min[at] < z_min + (THRESHOLD_M + SLOPE * d * cell))
        company += inside
        above += there & ~inside
    return (company < MIN_COMPANY) & (above >= MIN_ABOVE)
