"""From a cloud to network inputs and back: partition -> features -> compress -> voxelize ->
pack -> network -> soft vote.

Host code drives jitted array functions (`gfjax.sparsegf.programs`):

1. `partition` cuts the cloud into cylinders (R_oo = 150 m on a 50 m grid).
2. `prepare` (one patch): the per-point features on the patch's own points (`features`),
   then the context thinning, the rotation (training), the context compression (Eqs. 1-3)
   and the 0.5 m voxels, whose features are the mean of their points'. It keeps, for each
   central point, its voxel and its own features less the voxel's mean (what sets it apart
   from the other points of its voxel: the network's point head reads both).
3. `pack` concatenates patches into one sparse tensor, one batch index per patch, padded to
   `PACK_VOXELS` rows and their central points to `POINTS_PER_VOXEL` times as many (a patch
   larger than that alone, to the next power of two): one shape,
   so a machine compiles the network once, not once per patch shape (each compiled program
   also holds thousands of memory maps, and a process may only have 65,530). Every patch of a capacity shares one pyramid plan
   (`standard_plan`, grown from the data only when a pack does not fit it: `run_with_room`).
4. `programs.predict` runs the network on a pack: the ground probability of each central
   point, and `soft_vote` merges the patches (Algorithm 1).

Context thinning (a CPU budget, not in the paper): a patch keeps every central point and at
most `max_context_points` peripheral ones, drawn at random with a seed fixed by the patch; the
periphery is compressed about 4-13x in radius, so its voxels stay occupied.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import numpy as np

from gfjax.nn import sparse
from gfjax.nn.sparse import keys as K
from gfjax.sparsegf.partition import PartitionConfig, cylinders
from gfjax.sparsegf.programs import point_inputs
from gfjax.tiling.buckets import power_bucket

DEPTH = 4                  # levels of the U-Net below the input
PACK_VOXELS = 65_536       # voxel rows of a pack: patches are packed up to this many
MIN_POINTS = 4_096         # smallest point capacity of the per-patch feature program
# The padded sizes of a patch (its members, the points it keeps) whose feature program
# `gfjax warmup` compiles ahead (`programs.prepare_point_inputs`): members of a patch's 150 m
# cylinder from 16,384 (0.23 points/m²) to 2,097,152 (30 points/m²), kept points up to 131,072;
# a cloud sparser or denser than that compiles its own on first use (0.85 s each).
WARM_MEMBERS = tuple(2 ** i for i in range(14, 22))
WARM_KEPT = tuple(2 ** i for i in range(14, 18))
# The pack of a cloud whose patches hold this many voxels in all, or fewer: the network costs
# what its pack's capacity costs, so a few hundred points do not pay for `PACK_VOXELS` rows
# (a 30-point file: 2.9 s and 785 MB whole process with a full pack).
SMALL_PACK_VOXELS = 8_192
# The pack of a cloud whose patches cannot hold more voxels than this in all (its points
# times its patches: a voxel holds one point at least): a file of a few hundred points runs
# a program of 1,024 rows (about 10 MB of working memory instead of 80 MB at 8,192). Decided
# for the whole cloud, not per pack, so a larger cloud's last pack runs the program, and gets
# the votes, it always had.
TINY_PACK_VOXELS = 1_024
POINTS_PER_VOXEL = 4       # central point rows of a pack per voxel row
# Patches per network call at most when classifying. A pack costs about the same whatever it
# holds, so small patches (a sparse cloud's, a cloud's edges) share one; the batch index only
# keeps them apart, and the one compiled program serves every cloud.
PACK_SLOTS = 1024


class Patch(NamedTuple):
    """One voxelized patch (host numpy, exact sizes).

    Attributes:
      coords: `(m, 3)` int32 level-0 voxels (grid indices of the compressed patch).
      feats: `(m, f)` float32, the mean features of each voxel's points.
      point_index: `(c,)` int64, the cloud index of each central point.
      point_voxel: `(c,)` int32, the row of its voxel in `coords`.
      point_feats: `(c, f)` float32, its features less its voxel's (mean) features.
      patch_id: the patch's name in the partition (its row, or its cell of the frame's grid:
        `filter.patches`); it seeds the thinning of its context.
    """

    coords: np.ndarray
    feats: np.ndarray
    point_index: np.ndarray
    point_voxel: np.ndarray
    point_feats: np.ndarray
    patch_id: int

    def central_counts(self) -> np.ndarray:
        """Central points per voxel `(m,)` float32."""
        return np.bincount(self.point_voxel, minlength=len(self.coords)).astype(np.float32)


def thin_context(central: np.ndarray, max_points: int | np.integer, seed: int | np.integer) -> np.ndarray:
    """Rows to keep: every central one, and at most `max_points` peripheral ones drawn at random."""
    rest = np.flatnonzero(~central)
    if len(rest) <= max_points:
        return np.arange(len(central))
    keep = np.random.default_rng(seed).choice(rest, size=max_points, replace=False)
    return np.sort(np.concatenate([np.flatnonzero(central), keep]))


def voxelize(points: np.ndarray, feats: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxels of points `(n, 3)` [m] (host): `(coords (m, 3) int32, mean feats (m, f),
    voxel row of each point (n,))`, voxels in increasing (i, j, k) order.

    The same voxels as `gfjax.nn.sparse.voxelize` (tested), in numpy: that one is jitted and
    needs a static capacity, so it would compile once per patch size; here the sizes are exact.
    """
    grid = np.floor(points / voxel_m).astype(np.int64)
    low = grid.min(axis=0) if len(grid) else np.zeros(3, np.int64)
    span = (grid.max(axis=0) - low + 1) if len(grid) else np.ones(3, np.int64)
    key = ((grid[:, 0] - low[0]) * span[1] + (grid[:, 1] - low[1])) * span[2] + (grid[:, 2] - low[2])
    unique, inverse = np.unique(key, return_inverse=True)
    count = np.bincount(inverse, minlength=len(unique)).astype(np.float64)
    mean = np.stack([np.bincount(inverse, weights=feats[:, j], minlength=len(unique)) for j in range(feats.shape[1])],
                    axis=1) / np.maximum(count, 1)[:, None]
    k = unique % span[2]
    ij = unique // span[2]
    coords = np.stack([ij // span[1] + low[0], ij % span[1] + low[1], k + low[2]], axis=1)
    return coords.astype(np.int32), mean.astype(np.float32), inverse.astype(np.int32)


def _padded(a: np.ndarray, size: int, value=0) -> np.ndarray:
    out = np.full((size,) + a.shape[1:], value, a.dtype)
    out[:len(a)] = a
    return out


def prepare(xyz_m: np.ndarray, members: np.ndarray, center_m: np.ndarray, patch_id: int, *, config,
            angle: float = 0.0, seed: int = 0, cloud_feats: np.ndarray | None = None) -> Patch:
    """Voxelize one cylinder (`members`: its cloud indices) for the network; `cloud_feats`
    `(n, e)`: the cloud's per-point inputs computed once per cloud (`features.cloud_features`),
    appended to the patch's own."""
    local = np.empty((len(members), 3), np.float32)
    local[:, :2] = (xyz_m[members, :2] - center_m[None, :]).astype(np.float32)
    local[:, 2] = xyz_m[members, 2].astype(np.float32)
    # a superset of what `compress` will call central: those are never thinned away
    near = np.hypot(local[:, 0], local[:, 1]) <= config.r_in_m + 1e-3
    keep = thin_context(near, config.max_context_points, seed + patch_id)
    n, k = power_bucket(len(members), minimum=MIN_POINTS), power_bucket(len(keep), minimum=MIN_POINTS)
    pts, central, feats = jax.device_get(point_inputs(
        _padded(local, n), np.arange(n) < len(members), _padded(keep.astype(np.int32), k), np.arange(k) < len(keep),
        np.float32(angle), config=config))
    pts, central, feats = pts[:len(keep)], central[:len(keep)], feats[:len(keep)]
    if cloud_feats is not None:
        feats = np.concatenate([feats, cloud_feats[members[keep]]], axis=1)
    coords, vfeats, row = voxelize(pts, feats, config.voxel_m)
    return Patch(coords, vfeats, members[keep][central].astype(np.int64), row[central],
                 feats[central] - vfeats[row[central]], int(patch_id))


class Pack(NamedTuple):
    """Patches concatenated into one sparse tensor, padded to a capacity (host numpy).

    Attributes:
      coords: `(M, 4)` int32 `(b, i, j, k)`, `b` = the patch's slot; feats `(M, f)`;
      valid: `(M,)` bool; weight `(M,)` float32, central points per voxel.
      point_row: `(P,)` int32, the row of each central point's voxel (padding: 0);
      point_feats: `(P, f)` (`Patch.point_feats`); point_valid: `(P,)` bool.
      starts, point_starts: `(slots,)` first voxel row and first point row of each slot's
        patch (unused slots: M, P).
      patches: the patches, by slot.
      plan: the pyramid plan of this capacity.
    """

    coords: np.ndarray
    feats: np.ndarray
    valid: np.ndarray
    weight: np.ndarray
    point_row: np.ndarray
    point_feats: np.ndarray
    point_valid: np.ndarray
    starts: np.ndarray
    point_starts: np.ndarray
    patches: tuple[Patch, ...]
    plan: sparse.PyramidPlan

    @property
    def slots(self) -> int:
        return len(self.starts)

    def per_point(self, columns: list[np.ndarray]) -> np.ndarray:
        """`(P,)`: each patch's `(c,)` values of its central points at their rows, 0 elsewhere."""
        out = np.zeros(len(self.point_row), columns[0].dtype if columns else np.int32)
        for patch, start, values in zip(self.patches, self.point_starts, columns):
            out[start:start + len(patch.point_index)] = values
        return out


def pack(patches: list[Patch], slots: int, plans: dict[int, sparse.PyramidPlan] | None = None, *,
         min_capacity: int = PACK_VOXELS) -> Pack:
    """Concatenate up to `slots` patches (batch index = slot) into the smallest power of two
    (at least `min_capacity`) that holds them, their central points into `POINTS_PER_VOXEL`
    times as many rows (or more, a power of two times that, for a patch that needs it), with
    the plan kept in `plans` for that capacity (else `standard_plan`)."""
    if not 1 <= len(patches) <= slots:
        raise ValueError(f"pack: 1..{slots} patches, got {len(patches)}")
    total = sum(len(p.coords) for p in patches)
    size = power_bucket(total, minimum=min_capacity)
    n_points = sum(len(p.point_index) for p in patches)
    points = power_bucket(n_points, minimum=POINTS_PER_VOXEL * size)
    coords = np.zeros((size, 4), np.int32)
    feats = np.zeros((size, patches[0].feats.shape[1]), np.float32)
    weight = np.zeros(size, np.float32)
    point_row = np.zeros(points, np.int32)
    point_feats = np.zeros((points, patches[0].feats.shape[1]), np.float32)
    starts = np.full(slots, size, np.int64)
    point_starts = np.full(slots, points, np.int64)
    row = at = 0
    for slot, p in enumerate(patches):
        m, c = len(p.coords), len(p.point_index)
        coords[row:row + m, 0] = slot
        coords[row:row + m, 1:] = p.coords
        feats[row:row + m] = p.feats
        weight[row:row + m] = p.central_counts()
        point_row[at:at + c] = row + p.point_voxel
        point_feats[at:at + c] = p.point_feats
        starts[slot], point_starts[slot] = row, at
        row += m
        at += c
    K.check_range(coords, np.arange(size) < total, "sparsegf pack")
    plan = (plans or {}).get(size) or sparse.standard_plan(size, depth=DEPTH)
    return Pack(coords, feats, np.arange(size) < total, weight, point_row, point_feats, np.arange(points) < n_points,
                starts, point_starts, tuple(patches), plan)


def min_capacity(patches: list[Patch], *, cloud_voxels_at_most: int) -> int:
    """The smallest capacity `pack` pads these patches to: `TINY_PACK_VOXELS` when the whole
    cloud has at most that many voxels (`cloud_voxels_at_most`: an upper bound), else
    `SMALL_PACK_VOXELS` when these patches hold that many or fewer, else `PACK_VOXELS`."""
    if cloud_voxels_at_most <= TINY_PACK_VOXELS:
        return TINY_PACK_VOXELS
    return SMALL_PACK_VOXELS if sum(len(p.coords) for p in patches) <= SMALL_PACK_VOXELS else PACK_VOXELS


def fits_tiny_pack(xyz_m: np.ndarray, config) -> bool:
    """Whether the patches of the cloud `xyz_m` `(n, 3)` [m] cannot hold more than
    `TINY_PACK_VOXELS` voxels in all (its points times its patches), so that they run in
    one pack of that capacity (`min_capacity`); partitioned only when the points alone fit."""
    n = len(xyz_m)
    if not 0 < n <= TINY_PACK_VOXELS:
        return False
    return len(cylinders(xyz_m, PartitionConfig(step_m=config.step_m, r_oo_m=config.r_oo_m,
                                                 r_in_m=config.r_in_m))) * n <= TINY_PACK_VOXELS


def tiny_pack(n_features: int) -> Pack:
    """A pack of `TINY_PACK_VOXELS` rows holding one voxel: the shapes of a tiny cloud's pack
    (`programs.prepare_predict`)."""
    one = Patch(np.zeros((1, 3), np.int32), np.zeros((1, n_features), np.float32), np.zeros(1, np.int64),
                np.zeros(1, np.int32), np.zeros((1, n_features), np.float32), 0)
    return pack([one], PACK_SLOTS, min_capacity=TINY_PACK_VOXELS)


def group(patches, slots: int, max_voxels: int = PACK_VOXELS):
    """Lists of consecutive patches to pack: at most `slots` patches, `max_voxels` voxels and
    `POINTS_PER_VOXEL * max_voxels` central points each (a patch larger than that alone)."""
    out, voxels, points = [], 0, 0
    for p in patches:
        if out and (len(out) == slots or voxels + len(p.coords) > max_voxels
                    or points + len(p.point_index) > POINTS_PER_VOXEL * max_voxels):
            yield out
            out, voxels, points = [], 0, 0
        out.append(p)
        voxels += len(p.coords)
        points += len(p.point_index)
    if out:
        yield out


def grow_plan(packed: Pack) -> Pack:
    """The pack with a plan grown from its own voxels (a host pass)."""
    return packed._replace(plan=sparse.plan_pyramid(packed.coords, packed.valid, depth=DEPTH, like=packed.plan))


def run_with_room(run: Callable, packed: Pack, plans: dict[int, sparse.PyramidPlan]):
    """`run(packed) -> (result, overflowed)`, run again with a grown plan if the pack did not
    fit its plan; the grown plan is kept in `plans` for later packs of that capacity."""
    result, overflowed = run(packed)
    if bool(overflowed):
        packed = grow_plan(packed)
        plans[packed.plan.capacities[0]] = packed.plan
        result, overflowed = run(packed)
        if bool(overflowed):
            raise RuntimeError("sparsegf: a pyramid plan grown from the data did not fit the data")
    return result


def unpack(packed: Pack, point_values: np.ndarray) -> list[np.ndarray]:
    """Each patch's central points' values `(c,)`, read from per-point-row values `(P,)`."""
    return [point_values[start:start + len(p.point_index)] for p, start in zip(packed.patches, packed.point_starts)]
