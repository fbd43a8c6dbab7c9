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
    on = mask[..., None].astype(logits_cls.dtype)
    cls_counts = jax.nn.one_hot(jnp.where(mask, labels, 0), 2, dtype=logits_cls.dtype) * on
    bin_counts = jax.nn.one_hot(jnp.where(mask, hag_bins, 0), weights.shape[0], dtype=logits_cls.dtype) * on
    return _loss_of_counts(jnp.where(mask[..., None], logits_cls, 0.0), jnp.where(mask[..., None], logits_hag, 0.0),
                           cls_counts, bin_counts, weights, lam)


def _loss_of_counts(logits_cls, logits_hag, cls_counts, bin_counts, weights, lam):
    """Eqs. 4-5 from the one-hot counts `(..., 2)`, `(..., C)` of each row's class and bin."""
    n = jnp.sum(cls_counts)
    inv_n = jnp.where(n > 0, 1.0 / jnp.maximum(n, 1.0), 0.0)
    l_cls = -jnp.sum(cls_counts * jax.nn.log_softmax(logits_cls, axis=-1)) * inv_n
    w = weights.reshape((1,) * (bin_counts.ndim - 1) + (-1,))
    l_hag = -jnp.sum(w * bin_counts * jax.nn.log_softmax(logits_hag, axis=-1)) * inv_n           # Eq. 4
    total = (1.0 - lam) * l_cls + lam * l_hag                                                      # Eq. 5
    return HeightAwareLoss(total, l_cls, l_hag, n)
