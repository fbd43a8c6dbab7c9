"""Cylindrical partition of a cloud into SparseGF patches (Qin et al. 2026, Sec. 2 and 3.3).

The cloud is cut by a "sliding cylindrical window": vertical cylinders of radius
R_oo = 150 m whose axes stand on a square grid with a 50 m step. The grid is the set of
centres of 50 m cells tiling the cloud's x-y bounding box (centred on it; or a given box's,
a survey's frame, so every window of it shares one grid), so every point
lies in one *home* cell and is at most `step * sqrt(2) / 2 = 25 * sqrt(2) m = R_in` from its
home centre: the central regions (radius R_in, Sec. 3.3) cover every point at least once,
points on the cloud's edge and clouds smaller than one cell included. A point near a cell
corner or edge is central in up to four patches; `soft_vote` merges their predictions.

Host code (numpy; runs once per cloud, outside jit). Points are bucketed by home cell, and
each cylinder gathers the buckets its disc can reach and keeps the points within R_oo
(distances in float64). Patches whose central region is empty are dropped, and, given the
points whose labels are wanted (a survey window's core), those whose central region is far
from them. `cylinders` finds a patch's points when it is asked for them: a filter holds one
patch's memberships at a time, not the window's (each point lies in about 28 cylinders).
`partition` finds them all and pads them to a few capacity buckets (`2**j` and
`1.5 * 2**j`, `gfjax.tiling.buckets.capacity_bucket`) with a `valid` mask, grouped by
capacity, so one batch of each capacity runs under `jax.vmap` and only a handful of shapes
ever compile (the jax-md pattern: allocate outside jit, compute inside).
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from gfjax.errors import InputError
from gfjax.sparsegf.compress import CENTRAL_TOL_M, R_IN_M, R_OO_M
from gfjax.tiling.buckets import capacity_bucket

STEP_M = 50.0            # grid step of the patch centres [m] (Sec. 3.3)
MIN_CAPACITY = 256       # the smallest capacity bucket [points]


@dataclasses.dataclass(frozen=True)
class PartitionConfig:
    """Static geometry of the partition [m].

    `r_in_m` must be at least `step_m * sqrt(2) / 2` (the half diagonal of a grid cell),
    or the central regions would not cover the cloud; the paper uses equality.
    """

    step_m: float = STEP_M
    r_oo_m: float = R_OO_M
    r_in_m: float = R_IN_M
    min_capacity: int = MIN_CAPACITY

    def __post_init__(self):
        if not self.step_m > 0:
            raise InputError(f"partition: step_m must be > 0, got {self.step_m}")
        if self.r_in_m + CENTRAL_TOL_M < self.step_m * math.sqrt(2.0) / 2.0:
            raise InputError(f"partition: r_in_m={self.r_in_m} leaves gaps between central regions "
                             f"of a {self.step_m} m grid; need >= {self.step_m * math.sqrt(2) / 2:.4f}")
        if not self.r_oo_m >= self.r_in_m:
            raise InputError(f"partition: r_oo_m must be >= r_in_m, got {self.r_oo_m} < {self.r_in_m}")
        if self.min_capacity < 1:
            raise InputError(f"partition: min_capacity must be >= 1, got {self.min_capacity}")


class PatchBatch(NamedTuple):
    """Patches of one capacity, padded, ready for `jax.vmap`.

    Attributes:
      patch_id: `(b,)` int32, row of each patch in `Partition.centers_m`.
      center_m: `(b, 2)` float64, the cylinder axes, in the frame of the partitioned xyz [m].
      index: `(b, capacity)` int32, the cloud's point indices in each cylinder, grouped by
        the 50 m cell they lie in (increasing within a cell; with `partition`'s `box`, in the
        order of their x, y, z), then `-1` padding.
      valid: `(b, capacity)` bool, `index >= 0`.
    """

    patch_id: np.ndarray
    center_m: np.ndarray
    index: np.ndarray
    valid: np.ndarray

    @property
    def capacity(self) -> int:
        return int(self.index.shape[1])

    def local_xyz(self, xyz_m: np.ndarray) -> np.ndarray:
        """Patch-frame coordinates `(b, capacity, 3)`, float32 metres.

        `x, y` are relative to each patch's axis (so `compress(..., center=(0, 0))`), computed
        in float64 before the cast; `z` is `xyz_m`'s z, cast to float32. Padding rows are 0.
        """
        xyz_m = np.asarray(xyz_m)
        safe = np.where(self.valid, self.index, 0)
        out = np.empty(self.index.shape + (3,), dtype=np.float32)
        for axis in range(2):                                  # x, y: float64 difference, then cast
            column = np.ascontiguousarray(xyz_m[:, axis], dtype=np.float64)
            out[..., axis] = np.take(column, safe) - self.center_m[:, axis, None]
        out[..., 2] = np.take(np.ascontiguousarray(xyz_m[:, 2], dtype=np.float32), safe)
        out[~self.valid] = 0.0
        return out


class Partition(NamedTuple):
    """A cloud cut into overlapping cylinders.

    Attributes:
      centers_m: `(p, 2)` float64 patch axes in the input frame [m], row = `patch_id`.
      n_points: `(p,)` int64, points in each cylinder (`r <= r_oo_m`).
      batches: one `PatchBatch` per capacity bucket, increasing capacity.
      config: the geometry used.
      cells: `(p,)` int64, each patch's cell on the grid of the box it was laid on
        (`partition`'s `box`, row-major), the same in every window laid on that box.
    """

    centers_m: np.ndarray
    n_points: np.ndarray
    batches: tuple[PatchBatch, ...]
    config: PartitionConfig
    cells: np.ndarray


def grid_centers(xy_min: np.ndarray, xy_max: np.ndarray, step_m: float) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """Cell centres of a `step_m` grid centred on the box `[xy_min, xy_max]`.

    Returns:
      `(centers (ny * nx, 2) float64, (ny, nx), origin (2,))`: row-major over `(iy, ix)`;
      cell `(iy, ix)` spans `origin + [ix, ix + 1] * step_m` in x (likewise y).
    """
    origin, shape = _grid(xy_min, xy_max, step_m)
    return _centers(origin, shape, step_m), (int(shape[1]), int(shape[0])), origin


def _grid(xy_min: np.ndarray, xy_max: np.ndarray, step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """`(origin (2,), (nx, ny))` of `grid_centers`' grid."""
    xy_min, xy_max = np.asarray(xy_min, np.float64), np.asarray(xy_max, np.float64)
    extent = np.maximum(xy_max - xy_min, 0.0)
    shape = np.maximum(np.ceil(extent / step_m).astype(np.int64), 1)
    return xy_min - (shape * step_m - extent) / 2.0, shape


def _centers(origin: np.ndarray, shape: np.ndarray, step_m: float) -> np.ndarray:
    """The centres `(ny * nx, 2)` of the `shape` `(nx, ny)` cells of `step_m` from `origin`, row-major."""
    cx = origin[0] + (np.arange(shape[0]) + 0.5) * step_m
    cy = origin[1] + (np.arange(shape[1]) + 0.5) * step_m
    return np.stack(np.meshgrid(cx, cy, indexing="xy"), axis=-1).reshape(-1, 2)


class Cylinders:
    """A cloud's cylinders (`cylinders`): their axes, and each one's points found when asked
    for (`members`), so a cloud's patches cost one patch's memberships at a time, not the
    whole cloud's (every point lies in about 28 cylinders of the default geometry).

    Attributes:
      centers_m: `(p, 2)` float64 patch axes in the input frame [m].
      cells: `(p,)` int64, each patch's cell on the grid of the box it was laid on
        (`partition`'s `box`, row-major), the same in every window laid on that box.
      config: the geometry used.
    """

    def __init__(self, xyz_m: np.ndarray, order: np.ndarray, starts: np.ndarray, kept: np.ndarray, nx: int,
                 ny: int, centers_m: np.ndarray, cells: np.ndarray, config: PartitionConfig):
        self._xyz, self._order, self._starts, self._kept, self._nx, self._ny = xyz_m, order, starts, kept, nx, ny
        self.centers_m, self.cells, self.config = centers_m, cells, config

    def __len__(self) -> int:
        return len(self.centers_m)

    def members(self, p: int) -> np.ndarray:
        """The points within `r_oo_m` of patch `p`'s axis, int32 `(k,)` cloud indices grouped
        by the 50 m cell they lie in (`PatchBatch.index`'s order)."""
        cand = _near(self._order, self._starts, int(self._kept[p]), self._nx, self._ny, self.config.step_m,
                     self.config.r_oo_m)
        d = self._xyz[cand, :2].astype(np.float64) - self.centers_m[p]
        return cand[np.einsum("ij,ij->i", d, d) <= self.config.r_oo_m ** 2].astype(np.int32)


def _near(order: np.ndarray, starts: np.ndarray, cell: int, nx: int, ny: int, step_m: float,
          radius_m: float) -> np.ndarray:
    """The points of the cells any part of which lies within `radius_m` of `cell`'s centre,
    int64 `(k,)`, cell by cell in row-major order (`order[starts[c]:starts[c + 1]]`: cell `c`'s)."""
    reach = math.floor(radius_m / step_m + 0.5)                # cells a disc can touch, per axis
    iy, ix = divmod(cell, nx)
    runs = []
    for dy in range(-reach, reach + 1):
        if not 0 <= iy + dy < ny:
            continue
        gap_y = max(abs(dy) - 0.5, 0.0) * step_m               # nearest distance to that row of cells [m]
        for dx in range(-reach, reach + 1):
            if 0 <= ix + dx < nx and math.hypot(max(abs(dx) - 0.5, 0.0) * step_m, gap_y) <= radius_m:
                c = (iy + dy) * nx + ix + dx
                runs.append(order[starts[c]:starts[c + 1]])
    return np.concatenate(runs).astype(np.int64, copy=False) if runs else np.zeros(0, np.int64)


def cylinders(xyz_m: np.ndarray, config: PartitionConfig | None = None, *, shift_m=(0.0, 0.0),
              box: tuple[np.ndarray, np.ndarray] | None = None, core: np.ndarray | None = None,
              core_reach_m: float = 0.0) -> Cylinders:
    """The cylinders of radius `r_oo_m` on a `step_m` grid of axes that a cloud's points need,
    their members found one patch at a time (`Cylinders.members`).

    Args:
      xyz_m: points `(n, 3)` (or `(n, 2)`), metres; float64 absolute or float32 local.
      config: geometry (defaults: 50 m step, R_oo = 150 m, R_in = 25 sqrt(2) m).
      shift_m: `(dx, dy)` [m], moves the grid of axes by this much (modulo the step; the
        grid grows by a cell per axis to keep covering the cloud). Training draws it at
        random, so the central regions fall on new places each epoch.
      box: `(xy_min, xy_max)` [m], a box holding every point that the grid is laid on instead
        of the points' own (a survey's frame: its windows then share the whole survey's
        patches where they hold their points, each patch listing its points in the order of
        their coordinates whatever the window's order); only the cells the points reach are made.
      core: bool `(n,)`, the points whose labels are wanted (a survey window's core), or None
        for all: only the patches whose central region lies within `core_reach_m` [m] of one
        of them are made, so every point within `core_reach_m` of the core is voted on by
        every patch the whole cloud would vote on it with, and the rest of the window gives
        context only (`core_reach_m` is unused without `core`).

    Returns:
      `Cylinders`, in increasing cell order. Every core point (every point, without `core`)
      is within `r_in_m` of at least one kept axis. An empty cloud, or an empty core, gives none.
    """
    config = config or PartitionConfig()
    xyz_m = np.asarray(xyz_m)
    if xyz_m.ndim != 2 or xyz_m.shape[1] not in (2, 3):
        raise InputError(f"partition: xyz_m must have shape (n, 3), got {xyz_m.shape}")
    xy = xyz_m[:, :2].astype(np.float64)
    if not np.all(np.isfinite(xy)):
        raise InputError("partition: xyz_m has non-finite x or y")
    if core is not None and np.shape(core) != (len(xy),):
        raise InputError(f"partition: core must have shape ({len(xy)},), got {np.shape(core)}")
    if len(xy) >= 2 ** 31:
        raise InputError(f"partition: {len(xy)} points do not fit int32 indices; tile the cloud first")
    if len(xy) == 0 or (core is not None and not np.any(core)):
        return Cylinders(xyz_m, np.zeros(0, np.int32), np.zeros(1, np.int64), np.zeros(0, np.int64), 1, 1,
                         np.zeros((0, 2)), np.zeros(0, np.int64), config)

    step = config.step_m
    lows, highs = xy.min(axis=0), xy.max(axis=0)
    origin, shape = _grid(*((lows, highs) if box is None else box), step)
    shift = np.mod(np.asarray(shift_m, np.float64), step)
    if np.any(shift > 0):
        # one more cell per axis, so the shifted grid still covers the box
        origin, shape = origin - step + shift, shape + 1
    # the cells whose centres the points' central regions can reach (a box far larger than
    # the points costs nothing)
    reach_in = math.floor((config.r_in_m + CENTRAL_TOL_M) / step + 0.5)
    first = np.clip(np.floor((lows - origin) / step).astype(np.int64) - reach_in, 0, shape - 1)
    last = np.clip(np.floor((highs - origin) / step).astype(np.int64) + reach_in, first, shape - 1)
    whole_nx = int(shape[0])
    origin = origin + first * step
    nx, ny = (int(v) for v in last - first + 1)
    centers = _centers(origin, np.array([nx, ny]), step)
    home = np.clip(np.floor((xy[:, 1] - origin[1]) / step).astype(np.int64), 0, ny - 1) * nx
    home += np.clip(np.floor((xy[:, 0] - origin[0]) / step).astype(np.int64), 0, nx - 1)
    if box is None:
        order = np.argsort(home, kind="stable")                # points grouped by cell
    else:       # ... and within a cell by coordinates: a patch lists its points alike in any window
        keys = (xy[:, 1], xy[:, 0], home) if xyz_m.shape[1] == 2 else (xyz_m[:, 2], xy[:, 1], xy[:, 0], home)
        order = np.lexsort(keys)                               # the last key sorts first
    starts = np.searchsorted(home[order], np.arange(nx * ny + 1))
    order = order.astype(np.int32)
    if core is None:
        core_order, core_starts = order, starts
    else:
        mine = order[np.asarray(core, bool)[order]]            # the core's points, by cell as `order`
        core_order, core_starts = mine, np.searchsorted(home[mine], np.arange(nx * ny + 1))
    del home

    # a cell is kept when a point lies within r_in of its centre (the patch votes on it) and a
    # core point within r_in and the reach: such a point lies at most `reach` cells away, so
    # only the core's cells' neighbourhoods are visited, never the empty box (a sparse cloud
    # over a large extent costs its points)
    r_in = config.r_in_m + CENTRAL_TOL_M
    radius = r_in + (max(float(core_reach_m), 0.0) if core is not None else 0.0)
    reach = math.floor(radius / step + 0.5)

    def any_within(order, starts, cell: int, radius_m: float) -> bool:
        """Whether a point of `order` lies within `radius_m` (at least r_in) of `cell`'s centre."""
        if starts[cell + 1] > starts[cell]:                   # a cell's own points lie within r_in
            return True
        near = _near(order, starts, cell, nx, ny, step, radius_m)
        d = xy[near] - centers[cell]
        return bool(np.any(np.einsum("ij,ij->i", d, d) <= radius_m ** 2))

    occupied = np.flatnonzero(np.diff(core_starts))
    oy, ox = np.divmod(occupied, nx)
    around = []
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            y, x = oy + dy, ox + dx
            around.append((y * nx + x)[(y >= 0) & (y < ny) & (x >= 0) & (x < nx)])
    kept = [cell for cell in np.unique(np.concatenate(around)).tolist()
            if any_within(order, starts, cell, r_in)
            and (core is None or any_within(core_order, core_starts, cell, radius))]
    kept = np.asarray(kept, np.int64)
    cells = (kept // nx + first[1]) * whole_nx + kept % nx + first[0]
    return Cylinders(xyz_m, order, starts, kept, nx, ny, centers[kept], cells, config)


def partition(xyz_m: np.ndarray, config: PartitionConfig | None = None, *, shift_m=(0.0, 0.0),
              box: tuple[np.ndarray, np.ndarray] | None = None) -> Partition:
    """Cut a cloud into cylinders of radius `r_oo_m` on a `step_m` grid of axes, every
    patch's members found at once and padded into batches (`cylinders` finds them one patch
    at a time).

    Args:
      xyz_m, config, shift_m, box: as `cylinders`.

    Returns:
      A `Partition`. Every point is within `r_in_m` of at least one kept axis. An empty
      cloud gives no patches.
    """
    found = cylinders(xyz_m, config, shift_m=shift_m, box=box)
    members = [found.members(p) for p in range(len(found))]
    n_points = np.array([len(m) for m in members], dtype=np.int64)
    caps = np.array([capacity_bucket(int(n), minimum=found.config.min_capacity) for n in n_points], dtype=np.int64)
    batches = []
    for cap in np.unique(caps):
        ids = np.flatnonzero(caps == cap)
        index = np.full((len(ids), int(cap)), -1, dtype=np.int32)
        for row, pid in enumerate(ids):
            index[row, :n_points[pid]] = members[pid]
        batches.append(PatchBatch(patch_id=ids.astype(np.int32), center_m=found.centers_m[ids],
                                  index=index, valid=index >= 0))
    return Partition(centers_m=found.centers_m, n_points=n_points, batches=tuple(batches), config=found.config,
                     cells=found.cells)
