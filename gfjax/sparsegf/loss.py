"""SparseGF's height-aware loss (Qin et al. 2026, Sec. 2.2.2, Eqs. 4-5; settings Sec. 3.3).

    L_hag   = -(1/N) sum_i sum_c w_c y_ic log(yhat_ic)            (Eq. 4)
    L_cls   = -(1/N) sum_i log(yhat_i,label_i)                    (standard cross-entropy)
    L_total = (1 - lambda) L_cls + lambda L_hag                   (Eq. 5), lambda = 0.5

over the N central points of the patch (classification and loss are confined to the
geometrically intact central region, Sec. 2.2.1); C = 6 HAG bins with weights w_c rising
linearly 1..6 (Sec. 3.3).

Normalisation (a decision): Eq. 4 divides the weighted sum by N, the number of points, and
that is what this module does. It differs from PyTorch's `CrossEntropyLoss(weight=w)`, which
divides by `sum_i w_{c_i}`: that weighted mean cancels the weights on a patch whose points
all fall in one bin, whereas Eq. 4 keeps "a stronger penalty for taller objects" (the
paper's stated intent) on every patch. With all weights 1 both agree. N counts the central
valid points of everything passed in: call on one patch and average over a batch with
`jax.vmap`, or pass the whole batch `(b, n, ...)` at once to normalise by the batch's
central points (as a concatenated sparse batch would). A patch without central points
contributes 0 (and zero gradients).

Pure JAX; differentiable in the logits.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Bool, Float, Int

HAG_WEIGHTS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)   # w_c per HAG bin, linear 1..6 (Sec. 3.3)
LAMBDA = 0.5                                   # lambda in Eq. 5 (Sec. 3.3)


class HeightAwareLoss(NamedTuple):
    """Scalars: `total` (Eq. 5, what to minimise), its terms `cls` and `hag` (Eq. 4), and
    `n_central` (float32), the N both terms are divided by."""

    total: Float[Array, ""]
    cls: Float[Array, ""]
    hag: Float[Array, ""]
    n_central: Float[Array, ""]


def _masked_nll(logits, target, mask):
    """-log softmax(logits)[target] per point, 0 where `~mask` (padding may hold anything)."""
    logits = jnp.where(mask[..., None], logits, 0.0)
    target = jnp.where(mask, target, 0)
    log_p = jax.nn.log_softmax(logits, axis=-1)
    nll = -jnp.take_along_axis(log_p, target[..., None], axis=-1)[..., 0]
    return jnp.where(mask, nll, 0.0)


def height_aware_loss(logits_cls: Float[ArrayLike, "*n 2"], logits_hag: Float[ArrayLike, "*n c"],
                      labels: Int[ArrayLike, "*n"], hag_bins: Int[ArrayLike, "*n"],
                      central_mask: Bool[ArrayLike, "*n"], *,
                      weights: tuple[float, ...] = HAG_WEIGHTS,
                      lam: float | Float[Array, ""] = LAMBDA) -> HeightAwareLoss:
    """Height-aware loss of a patch (or a batch) of central points (Eqs. 4-5).

    Args:
      logits_cls: `(..., 2)` float, ground/non-ground logits; index 1 is ground.
      logits_hag: `(..., C)` float, HAG-bin logits, `C = len(weights)` (6).
      labels: `(...)` int, 1 = ground, 0 = non-ground.
      hag_bins: `(...)` int in `0..C-1` (`hag_targets(...).bins`).
      central_mask: `(...)` bool, the points scored: central AND valid
        (`compress(..., valid=valid).central`). Values of other rows are ignored, even NaN.
      weights: `w_c` per HAG bin (default 1..6).
      lam: lambda in `[0, 1]`, the weight of the HAG term (default 0.5).

    Returns:
      `HeightAwareLoss(total, cls, hag, n_central)`, float32 scalars; all 0 when no point is
      central. Jit-able; `jax.grad(lambda l: height_aware_loss(l, ...).total)` works.
    """
    logits_cls, logits_hag, labels, hag_bins, central_mask = (
        jnp.asarray(a) for a in (logits_cls, logits_hag, labels, hag_bins, central_mask))
    shape = central_mask.shape
    if labels.shape != shape or hag_bins.shape != shape:
        raise ValueError(f"height_aware_loss: labels {labels.shape} and hag_bins {hag_bins.shape} "
                         f"must have the shape of central_mask {shape}")
    if logits_cls.shape != shape + (2,):
        raise ValueError(f"height_aware_loss: logits_cls must have shape {shape + (2,)}, got {logits_cls.shape}")
    if logits_hag.shape != shape + (len(weights),):
        raise ValueError(f"height_aware_loss: logits_hag must have shape {shape + (len(weights),)} "
                         f"(one logit per weight), got {logits_hag.shape}")
    if isinstance(lam, (int, float)) and not 0.0 <= lam <= 1.0:
        raise ValueError(f"height_aware_loss: lam must be in [0, 1], got {lam}")
    return _height_aware_loss(logits_cls, logits_hag, labels, hag_bins, central_mask,
                              jnp.asarray(weights, dtype=logits_hag.dtype), lam)


@jax.jit
def _height_aware_loss(logits_cls, logits_hag, labels, hag_bins, mask, weights, lam):
    mask = mask.astype(bool)
    labels = labels.astype(jnp.int32)
    hag_bins = hag_bins.astype(jnp.int32)
    n = jnp.sum(mask, dtype=logits_cls.dtype)
    inv_n = jnp.where(n > 0, 1.0 / jnp.maximum(n, 1.0), 0.0)
    l_cls = jnp.sum(_masked_nll(logits_cls, labels, mask)) * inv_n
    w = weights[jnp.where(mask, hag_bins, 0)]                  # w_c of each point's true bin
    l_hag = jnp.sum(w * _masked_nll(logits_hag, hag_bins, mask)) * inv_n     # Eq. 4
    total = (1.0 - lam) * l_cls + lam * l_hag                                  # Eq. 5
    return HeightAwareLoss(total, l_cls, l_hag, n)
