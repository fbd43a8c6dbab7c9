"""From a cloud to network inputs and back: partition -> compress -> voxelize -> network -> vote.

Host code drives jitted array functions:

1. `partition` cuts the cloud into cylinders (R_oo = 150 m on a 50 m grid).
2. Per patch, `_compress_features` (jit) applies the context compression (Eqs. 1-3) and
   makes the per-point input features; `voxelize` (jit) bins the compressed points into
   0.5 m voxels. The voxel rows are cut to a capacity bucket of the patch's own count.
3. Patches of one voxel capacity share one pyramid plan (`standard_plan`, grown from the
   data only when a patch does not fit) and run under `jax.vmap`, so a capacity compiles once.
4. Each patch's central ground probabilities go to `soft_vote` (Algorithm 1).

Context thinning (a CPU budget, not in the paper): a patch keeps every central point, and at
most `max_context_points` points in all, the peripheral ones chosen at random with a seed
fixed by the patch; the periphery is compressed about 4-13x, so its voxels stay occupied.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from gfjax.nn import sparse
from gfjax.sparsegf.compress import compress
from gfjax.sparsegf.model import SparseGFNet

Z_SCALE_M = 10.0        # heights enter the network as (z - patch mean) / Z_SCALE_M [-]


class Patch(NamedTuple):
    """One voxelized patch (host numpy, rows padded to buckets).

    Attributes:
      index: `(n,)` int32 cloud index of each point (-1 padding).
      central: `(n,)` bool, points the network classifies.
      coords: `(m, 4)` int32 level-0 voxels; feats `(m, f)` their mean features; vvalid `(m,)`.
      point_voxel: `(n,)` int32 row of each point's voxel (-1 padding).
      patch_id: the patch's row in the partition.
    """

    index: np.ndarray
    central: np.ndarray
    coords: np.ndarray
    feats: np.ndarray
    vvalid: np.ndarray
    point_voxel: np.ndarray
    patch_id: int


@functools.partial(jax.jit, static_argnames=("r_in", "r_oc", "r_oo", "use_compression"))
def _compress_features(local_xyz, valid, angle, *, r_in, r_oc, r_oo, use_compression):
    """Rotated, compressed xyz `(n, 3)`, central mask and features `(n, 4)` of one patch."""
    c, s = jnp.cos(angle), jnp.sin(angle)
    rot = jnp.stack([jnp.stack([c, -s]), jnp.stack([s, c])])
    xy = local_xyz[:, :2] @ rot.T
    xyz = jnp.concatenate([xy, local_xyz[:, 2:]], axis=1)
    out = compress(xyz, jnp.zeros(2, jnp.float32), r_in=r_in, r_oc=r_oc, r_oo=r_oo, valid=valid)
    pts = out.xyz if use_compression else xyz
    w = valid.astype(jnp.float32)
    z_mean = jnp.sum(pts[:, 2] * w) / jnp.maximum(jnp.sum(w), 1.0)
    pts = jnp.concatenate([pts[:, :2], pts[:, 2:] - z_mean], axis=1)
    feats = jnp.stack([pts[:, 0] / r_oc, pts[:, 1] / r_oc, pts[:, 2] / Z_SCALE_M, jnp.ones_like(pts[:, 0])], axis=1)
    return pts, out.central, jnp.where(valid[:, None], feats, 0.0)


def bucket(n: int, minimum: int = 16384) -> int:
    """The power of two (at least `minimum`) holding `n`: few compiled shapes, since one
    compile of the network costs seconds to tens of seconds on a CPU."""
    size = minimum
    while size < n:
        size *= 2
    return size


def thin_context(index: np.ndarray, central: np.ndarray, max_points: int, seed: int) -> np.ndarray:
    """Rows to keep: every central one, and peripheral ones at random up to `max_points`."""
    if len(index) <= max_points:
        return np.arange(len(index))
    rng = np.random.default_rng(seed)
    core = np.flatnonzero(central)
    rest = np.flatnonzero(~central)
    room = max(max_points - len(core), 0)
    keep = rng.choice(rest, size=min(room, len(rest)), replace=False) if room else np.zeros(0, np.int64)
    return np.sort(np.concatenate([core, keep]))


def make_patch(xyz_m: np.ndarray, members: np.ndarray, center_m: np.ndarray, patch_id: int, *, config,
               angle: float = 0.0, seed: int = 0) -> Patch:
    """Voxelize one cylinder (`members`: its cloud indices) for the network."""
    local = np.empty((len(members), 3), np.float32)
    local[:, :2] = (xyz_m[members, :2] - center_m[None, :]).astype(np.float32)
    local[:, 2] = xyz_m[members, 2].astype(np.float32)
    central = np.hypot(local[:, 0], local[:, 1]) <= config.r_in_m + 1e-4
    keep = thin_context(members, central, config.max_context_points, seed + patch_id)
    members, local = members[keep], local[keep]
    n = bucket(len(members))
    pad = n - len(members)
    local = np.concatenate([local, np.zeros((pad, 3), np.float32)])
    valid = np.arange(n) < len(members)
    index = np.concatenate([members.astype(np.int32), np.full(pad, -1, np.int32)])
    pts, central, feats = _compress_features(jnp.asarray(local), jnp.asarray(valid), jnp.float32(angle),
                                             r_in=config.r_in_m, r_oc=config.r_oc_m, r_oo=config.r_oo_m,
                                             use_compression=config.compression)
    vox = sparse.voxelize(pts, feats, 0, config.voxel_m, valid=valid, capacity=n)
    count = int(np.sum(np.asarray(vox.tensor.valid)))
    m = bucket(count)
    m_rows = min(m, n)
    coords = np.zeros((m, 4), np.int32)
    vfeats = np.zeros((m, feats.shape[1]), np.float32)
    coords[:m_rows] = np.asarray(vox.tensor.coords)[:m_rows]
    vfeats[:m_rows] = np.asarray(vox.tensor.feats)[:m_rows]
    return Patch(index, np.asarray(central), coords, vfeats, np.arange(m) < count, np.asarray(vox.point_voxel),
                 patch_id)


class Batch(NamedTuple):
    """Patches stacked for `jax.vmap` (a `Patch` of arrays with a leading axis b; `patch_id`
    `(b,)`) and the pyramid plan they share."""

    patch: Patch
    plan: sparse.PyramidPlan


DEPTH = 4               # levels of the U-Net below the input


def stack(patches: list[Patch], plans: dict[int, sparse.PyramidPlan] | None = None) -> Batch:
    """Pad patches to common sizes, with the plan kept in `plans` for their voxel capacity
    (else `standard_plan`, which depends on the capacity only: one compiled shape per
    capacity; `run_with_room` grows it for data that do not fit)."""
    n = max(len(p.index) for p in patches)
    m = max(len(p.coords) for p in patches)

    def pad(a, size, value):
        extra = size - a.shape[0]
        return np.concatenate([a, np.full((extra,) + a.shape[1:], value, a.dtype)]) if extra else a

    plan = (plans or {}).get(m) or sparse.standard_plan(m, depth=DEPTH)
    stacked = Patch(np.stack([pad(p.index, n, -1) for p in patches]), np.stack([pad(p.central, n, False) for p in patches]),
                    np.stack([pad(p.coords, m, 0) for p in patches]), np.stack([pad(p.feats, m, 0) for p in patches]),
                    np.stack([pad(p.vvalid, m, False) for p in patches]),
                    np.stack([pad(p.point_voxel, n, -1) for p in patches]), np.asarray([p.patch_id for p in patches]))
    return Batch(stacked, plan)


def grow_plan(batch: Batch) -> Batch:
    """The batch with a plan grown from its own voxels (a host pass over every patch)."""
    plan = batch.plan
    for coords, valid in zip(batch.patch.coords, batch.patch.vvalid):
        plan = sparse.plan_pyramid(coords, valid, depth=DEPTH, like=plan)
    return batch._replace(plan=plan)


def run_with_room(run, batch: Batch, plans: dict[int, sparse.PyramidPlan]):
    """`run(batch) -> (result, overflowed)`, run again with a grown plan if the batch did not
    fit its plan; the grown plan is kept in `plans` for later batches of that capacity."""
    result, overflowed = run(batch)
    if bool(overflowed):
        batch = grow_plan(batch)
        plans[batch.plan.capacities[0]] = batch.plan
        result, overflowed = run(batch)
        if bool(overflowed):
            raise RuntimeError("sparsegf: a pyramid plan grown from the data did not fit the data")
    return result


def forward(net: SparseGFNet, coords, feats, vvalid, point_voxel, central, plan):
    """Logits of one patch and whether its pyramid overflowed `plan` (jit-able with `plan`
    static; vmap over patches)."""
    pyramid = sparse.build_pyramid(coords, vvalid, plan)
    x = sparse.SparseTensor(coords, jnp.where(vvalid[:, None], feats, 0.0), vvalid)
    return net(x, pyramid, point_voxel, central), pyramid.overflowed


@eqx.filter_jit
def predict_batch(net: SparseGFNet, coords, feats, vvalid, point_voxel, central, plan):
    """Ground probability `(b, n)` of every point of a batch (0 outside the central mask), and
    whether any patch overflowed `plan` (the probabilities are then wrong)."""
    out, overflowed = jax.vmap(lambda c, f, v, pv, ce: forward(net, c, f, v, pv, ce, plan))(
        coords, feats, vvalid, point_voxel, central)
    return jax.nn.softmax(out.cls, axis=-1)[..., 1], jnp.any(overflowed)
