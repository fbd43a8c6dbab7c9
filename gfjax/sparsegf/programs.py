"""SparseGF's compiled programs: a patch's input features, and the network over a pack.

- `point_inputs` (one patch, padded to a power of two of points: `pipeline.MIN_POINTS` and up)
  rotates, compresses and centres the kept points and computes their features; kept across
  processes by the program store (`gfjax.aot`: no tracing in a later process), and
  `gfjax warmup` prepares it ahead for the common sizes (`prepare_point_inputs`).
- `predict` runs the network on a pack's arrays (`Inputs`, `forward`) in inference mode; the
  program is kept across processes by the program store (`gfjax.aot`): its arguments are
  arrays, and the rest of the network (layer settings, the inference flags) is static.
  Training runs `forward` in programs of its own (`gfjax.sparsegf.train`).
- `vote` merges a cloud's votes (`vote.soft_vote`'s program, kept by the program store too).
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from gfjax import aot
from gfjax.nn import sparse
from gfjax.sparsegf import features as F
from gfjax.sparsegf.compress import compress
from gfjax.sparsegf.model import Model, SparseGFNet
from gfjax.sparsegf.vote import Vote, _soft_vote

__all__ = ["point_inputs", "prepare_point_inputs", "Inputs", "inputs", "forward", "predict_points", "predict",
           "prepare_predict", "vote"]


@functools.partial(jax.jit, static_argnames=("features", "r_in", "r_oc", "r_oo", "use_compression"))
def _point_inputs(local_xyz, valid, keep, keep_valid, angle, *, features, r_in, r_oc, r_oo, use_compression):
    """Compressed xyz `(k, 3)` (z relative to the patch's mean), central mask `(k,)` and input
    features `(k, f)` of the kept points `local_xyz[keep]` of one patch; every valid point of
    `local_xyz` `(n, 3)` shapes the top-hat surfaces."""
    kept = local_xyz[keep]
    c, s = jnp.cos(angle), jnp.sin(angle)
    rot = jnp.stack([jnp.stack([c, -s]), jnp.stack([s, c])])
    xyz = jnp.concatenate([kept[:, :2] @ rot.T, kept[:, 2:]], axis=1)
    out = compress(xyz, jnp.zeros(2, jnp.float32), r_in=r_in, r_oc=r_oc, r_oo=r_oo, valid=keep_valid)
    pts = out.xyz if use_compression else xyz
    z_mean = jnp.sum(jnp.where(keep_valid, pts[:, 2], 0.0)) / jnp.maximum(jnp.sum(keep_valid), 1).astype(pts.dtype)
    pts = pts.at[:, 2].add(-z_mean)
    f = F.xyz_features(pts, keep_valid, r_oc_m=r_oc)
    if features != "xyz":
        # heights over the surfaces of all the patch's points, before thinning, rotation (a
        # property of the point, not of the augmentation) and compression
        surfaces = F.tophat_surfaces(local_xyz, valid, half_extent_m=r_oo)
        f = jnp.concatenate([f, F.signed_log(F.heights_above(surfaces, kept, keep_valid, half_extent_m=r_oo))], axis=1)
    return pts, out.central, f


def _statics(config) -> dict:
    """The static arguments of `_point_inputs` under `config`."""
    return dict(features=config.features, r_in=config.r_in_m, r_oc=config.r_oc_m, r_oo=config.r_oo_m,
                use_compression=config.compression)


def point_inputs(local_xyz: np.ndarray, valid: np.ndarray, keep: np.ndarray, keep_valid: np.ndarray,
                 angle: np.float32, *, config):
    """`(xyz (k, 3), central (k,), features (k, f))` of one patch's kept points, device arrays.

    Args:
      local_xyz: float32 `(n, 3)` the patch's members [m], x, y about its centre; valid: bool `(n,)`.
      keep: int32 `(k,)` rows of `local_xyz` kept (context thinning); keep_valid: bool `(k,)`.
      angle: float32 rotation about z [rad].
      config: the patch settings (feature set, radii, compression; static).
    """
    return aot.call(_point_inputs, local_xyz, valid, keep, keep_valid, angle, **_statics(config))


def prepare_point_inputs(config, members: int, kept: int) -> None:
    """Load, or compile and store, without running it, the feature program `point_inputs` runs
    for a patch padded to `members` points of which `kept` are kept (powers of two, at least
    `pipeline.MIN_POINTS`): the program store keeps it (`gfjax warmup`; nothing when it is off)."""
    spec = jax.ShapeDtypeStruct
    aot.prefetch(_point_inputs, spec((members, 3), np.float32), spec((members,), np.bool_), spec((kept,), np.int32),
                 spec((kept,), np.bool_), spec((), np.float32), **_statics(config))


class Inputs(NamedTuple):
    """The arrays of a pack that the network reads (`pipeline.Pack`'s fields of the same names)."""

    coords: jax.Array
    feats: jax.Array
    valid: jax.Array
    weight: jax.Array
    point_row: jax.Array
    point_feats: jax.Array
    point_valid: jax.Array


def inputs(packed) -> Inputs:
    """The network's arrays of `packed` (a `pipeline.Pack`; its plan and slot count are passed
    as static)."""
    return Inputs(*(getattr(packed, name) for name in Inputs._fields))


def forward(net: SparseGFNet, state, x: Inputs, plan, slots: int):
    """Per-point logits of a pack's central points, the new state and whether its pyramid
    overflowed `plan` (jit-able with `plan` and `slots` static)."""
    pyramid = sparse.build_pyramid(x.coords, x.valid, plan)
    voxels = sparse.SparseTensor(x.coords, jnp.where(x.valid[:, None], x.feats, 0.0), x.valid, 1, slots)
    out, state = net(voxels, pyramid, x.weight, x.point_row, x.point_feats, x.point_valid, state)
    return out, state, pyramid.overflowed


@functools.partial(jax.jit, static_argnames=("skeleton", "plan", "slots"))
def predict_points(arrays, state, x: Inputs, *, skeleton, plan: sparse.PyramidPlan, slots: int):
    """Ground probability `(P,)` of every central point of a pack and whether it overflowed
    `plan`; the network is `eqx.combine(arrays, skeleton)`, its batch norms in inference mode."""
    out, _, overflowed = forward(eqx.combine(arrays, skeleton), state, x, plan, slots)
    return jax.nn.softmax(out.cls, axis=-1)[:, 1], overflowed


def predict(model: Model, packed):
    """Ground probability `(P,)` of every central point row of a pack (a `pipeline.Pack`;
    meaningful where `point_valid`) and whether the pack overflowed its plan (the probabilities
    are then wrong). Returns JAX arrays without waiting for them (asynchronous dispatch). The
    program is kept across processes when `gfjax.aot` is on (the command line turns it on)."""
    arrays, skeleton = _inference_split(model)
    return aot.call(predict_points, arrays, model.state, inputs(packed), skeleton=skeleton, plan=packed.plan,
                    slots=packed.slots)


def prepare_predict(model: Model, packed) -> None:
    """Load (or compile and store) the program `predict(model, packed)` runs, without running
    it: only the shapes of `packed` count (nothing when the program store is off)."""
    arrays, skeleton = _inference_split(model)
    aot.prefetch(predict_points, arrays, model.state, inputs(packed), skeleton=skeleton, plan=packed.plan,
                 slots=packed.slots)


_SPLIT: dict[int, tuple] = {}


def _inference_split(model: Model):
    """`(arrays, skeleton)` of the model's network in inference mode, made once per model: the
    same skeleton object every call, so the program cache prints it once."""
    known = _SPLIT.get(id(model))
    if known is None or known[0] is not model:
        _SPLIT.clear()
        known = _SPLIT[id(model)] = (model, *eqx.partition(eqx.nn.inference_mode(model.net), eqx.is_array))
    return known[1], known[2]


def vote(point_index: np.ndarray, prob_ground: np.ndarray, n_points: int) -> Vote:
    """`vote.soft_vote(point_index, prob_ground, n_points)` of host votes, every one counted
    (`(v,)` int cloud indices, -1 for padding, and float32 probabilities), through the program
    store: a later process loads the program without tracing it."""
    index = np.asarray(point_index, np.int32)
    return aot.call(_soft_vote, index, np.asarray(prob_ground, np.float32), np.ones(index.shape, bool),
                    n_points=int(n_points))

