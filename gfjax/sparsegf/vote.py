"""Soft voting: merge the predictions of overlapping central regions (Qin et al. 2026, Sec. 2.3,
Algorithm 1).

A point near the corner of a grid cell is central in up to four patches. Each such patch
gives it a ground probability; the merged probability is their mean

    D[p] = sum of prob(p) over its votes,  C[p] = number of votes,  prob[p] = D[p] / C[p]

and the point is ground iff `prob[p] > 0.5` (a tie, exactly 0.5, is non-ground, as in
Algorithm 1 line 10). Algorithm 1 labels only points with `C[p] > 0`; here a point with no
vote keeps `count == 0` and `label == UNCOVERED` (-1) rather than a silent non-ground label,
so callers can detect a partition that missed points (`partition` never does).

`decide` turns the mean votes into labels: the paper's threshold, or the network arbitrating
SMRF's verdict (`Config.decision`).

Pure JAX (`jax.ops.segment_sum`); jit-able, vmap-able over independent sets of votes.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike
from jaxtyping import Array, Bool, Float, Int

from gfjax.sparsegf.config import Config

UNCOVERED = -1   # label of a point that no patch classified
GROUND = 1
NON_GROUND = 0


class Vote(NamedTuple):
    """Per original point, shape `(n_points,)` each.

    Attributes:
      prob_ground: float, mean ground probability over the votes; 0 where `count == 0`.
      count: int32, number of votes (patches whose central region holds the point).
      label: int32, 1 ground (`prob_ground > 0.5`), 0 non-ground, -1 (`UNCOVERED`) no vote.
    """

    prob_ground: Float[Array, " n"]
    count: Int[Array, " n"]
    label: Int[Array, " n"]


def soft_vote(point_index: Int[ArrayLike, "*v"], prob_ground: Float[ArrayLike, "*v"], n_points: int | np.integer, *,
              mask: Bool[ArrayLike, "*v"] | None = None) -> Vote:
    """Mean ground probability per original point over the patches that classified it.

    Args:
      point_index: `(...)` int, the cloud index of each vote (e.g. `PatchBatch.index`,
        `(b, capacity)`). Indices outside `[0, n_points)` (such as the `-1` padding) are
        ignored.
      prob_ground: `(...)` float in `[0, 1]`, the predicted ground probability of each vote.
      n_points: number of points of the cloud (static).
      mask: optional `(...)` bool, the votes to count; pass the central mask, because only
        central points are classified (Sec. 2.2.1).

    Returns:
      `Vote(prob_ground, count, label)`, each `(n_points,)`. The result does not depend on
      the order of the votes (up to float rounding of the sums).
    """
    point_index, prob_ground = jnp.asarray(point_index), jnp.asarray(prob_ground)
    if point_index.shape != prob_ground.shape:
        raise ValueError(f"soft_vote: point_index {point_index.shape} and prob_ground "
                         f"{prob_ground.shape} must have the same shape")
    if mask is not None and jnp.shape(mask) != point_index.shape:
        raise ValueError(f"soft_vote: mask must have shape {point_index.shape}, got {jnp.shape(mask)}")
    if not isinstance(n_points, (int, np.integer)) or isinstance(n_points, bool) or n_points < 0:
        raise ValueError(f"soft_vote: n_points must be an int >= 0, got {n_points!r}")
    n_points = int(n_points)
    mask = jnp.ones(point_index.shape, dtype=bool) if mask is None else jnp.asarray(mask)
    return _soft_vote(point_index, prob_ground, mask, n_points=n_points)


@functools.partial(jax.jit, static_argnames="n_points")
def _soft_vote(point_index, prob_ground, mask, *, n_points):
    index = point_index.reshape(-1).astype(jnp.int32)
    use = mask.reshape(-1) & (index >= 0) & (index < n_points)
    index = jnp.where(use, index, 0)
    prob = jnp.where(use, prob_ground.reshape(-1), 0.0)
    total = jax.ops.segment_sum(prob, index, num_segments=n_points)             # D
    count = jax.ops.segment_sum(use.astype(jnp.int32), index, num_segments=n_points)   # C
    mean = total / jnp.maximum(count, 1).astype(total.dtype)
    label = jnp.where(count > 0, jnp.where(mean > 0.5, GROUND, NON_GROUND), UNCOVERED)
    return Vote(mean, count, label.astype(jnp.int32))


def decide(prob_ground: Float[ArrayLike, " n"], smrf_ground: Bool[ArrayLike, " n"] | None = None, *,
           config: Config) -> Bool[ArrayLike, " n"]:
    """Ground labels `(n,)` from mean votes `(n,)` (`Vote.prob_ground`), by `config.decision`.

    `"network"` (Algorithm 1): `prob_ground > ground_probability`. `"network+smrf"`: the
    threshold is `smrf_ground_probability` where SMRF calls the point ground (`smrf_ground`,
    `smrf_prior.smrf_heights`' margin >= 0) and `smrf_object_probability` elsewhere: with
    0.3 and 0.9, SMRF's verdict stands unless the network is confident against it. A point
    with no vote (`prob_ground` 0) is never ground.

    float32 numpy votes (the filter's) are decided in numpy, with the same float32 thresholds:
    a JAX op on a new cloud size would trace and compile each time; anything else in JAX.
    """
    host = isinstance(prob_ground, np.ndarray) and prob_ground.dtype == np.float32 and (
        smrf_ground is None or isinstance(smrf_ground, np.ndarray))
    xp = np if host else jnp
    prob_ground = xp.asarray(prob_ground)
    if config.decision == "network":
        return prob_ground > xp.float32(config.ground_probability)
    if smrf_ground is None:
        raise ValueError(f"decide: the decision {config.decision!r} needs SMRF's verdict (smrf_ground)")
    smrf_ground = xp.asarray(smrf_ground)
    if smrf_ground.shape != prob_ground.shape:
        raise ValueError(f"decide: smrf_ground {smrf_ground.shape} and prob_ground {prob_ground.shape} differ")
    threshold = xp.where(smrf_ground, xp.float32(config.smrf_ground_probability),
                         xp.float32(config.smrf_object_probability))
    return prob_ground > threshold
