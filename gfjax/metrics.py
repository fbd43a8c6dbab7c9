"""Accuracy of a ground filter: point metrics, DTM metrics, and a differentiable confusion.

Ground is the positive class (SPEC section 8). With `tp` ground labelled ground, `fp` object
labelled ground, `fn` ground labelled object, `tn` object labelled object, `n` their sum:

- `oa = (tp + tn) / n`, `total_error = (fp + fn) / n` (Sithole & Vosselman 2004),
- `type1 = fn / (tp + fn)` (ground rejected / ground), `type2 = fp / (fp + tn)` (object
  accepted / object),
- `kappa = (p_o - p_e) / (1 - p_e)` with `p_o = oa` and the usual chance agreement
  `p_e = ((tp + fp)(tp + fn) + (fn + tn)(fp + tn)) / n**2` (Cohen 1960; Wu et al. 2025,
  Eq. 9-10; their Eq. 11 prints a product of the four marginals, a typo),
- `f1 = 2 tp / (2 tp + fp + fn)`, `iou_ground = tp / (tp + fp + fn)`,
  `iou_nonground = tn / (tn + fp + fn)` (Wu et al. 2025, Eq. 5-8; SparseGF's "IoU1/IoU2").

All values are fractions in [0, 1], never percent. Conventions where a ratio is 0/0, so that
no-ground, all-ground and empty inputs give numbers, not NaN:
- `type1 = 0` without reference ground, `type2 = 0` without reference objects;
- `oa = 1`, `total_error = 0` for an empty input;
- `f1 = iou_ground = 1` when neither prediction nor reference holds ground, and
  `iou_nonground = 1` when neither holds an object (perfect agreement on an absent class);
- `kappa = 1` when `p_e = 1`: that happens only when prediction and reference are both all one
  and the same class, i.e. when they agree everywhere (kappa = 0 would be returned for a
  disagreement, which `p_e = 1` cannot produce). An empty input also gives kappa = 1.

`kappa` is computed in exact integer arithmetic, `(n (tp + tn) - S) / (n**2 - S)` with
`S = n**2 p_e`, so it has no rounding trouble on large clouds.

DTM metrics follow Wu et al. (2025), Sec. 3.1, Eq. 12-13 (cell means at 2 m, no gap filling).
Across samples, report `mean_over_samples` (unweighted mean of per-sample figures), the papers'
convention, not a figure pooled over all points.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from gfjax.errors import InputError

# Classes left out of every score against a vendor's classification: noise (7, 18), which no
# filter labels, and water (9) and overlap (12), which vendors keep apart from ground by rules
# of their own (`../shared/data/corpus/README.md`). Everything else but class 2 is non-ground.
UNSCORED_CLASSES = (7, 9, 12, 18)

POINT_KEYS = ("oa", "total_error", "type1", "type2", "kappa", "f1", "iou_ground",
              "iou_nonground", "n_points", "tp", "fp", "fn", "tn")
DTM_KEYS = ("rmse_m", "mean_diff_m", "r_o", "r_m", "share_lt_1m", "share_1_2m", "share_2_3m",
            "share_ge_3m", "n_cells_both")


def _as_labels(name: str, a, n: int | None = None) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype != np.bool_:
        raise InputError(f"{name} must be a bool array (True = ground), got dtype {a.dtype}")
    if a.ndim != 1 or (n is not None and a.shape[0] != n):
        want = f"({n},)" if n is not None else "(n,)"
        raise InputError(f"{name} must have shape {want}, got {a.shape}")
    return a


def _ratio(num: int, den: int, if_empty: float) -> float:
    return num / den if den else if_empty


def confusion(pred_ground, ref_ground, mask=None) -> tuple[int, int, int, int]:
    """Confusion counts with ground as the positive class.

    Args:
      pred_ground: predicted ground, bool `(n,)`.
      ref_ground: reference ground, bool `(n,)`.
      mask: points to score, bool `(n,)` (default: all), e.g. `~cloud.ignored`.

    Returns:
      `(tp, fp, fn, tn)` as Python ints.
    """
    pred = _as_labels("pred_ground", pred_ground)
    ref = _as_labels("ref_ground", ref_ground, pred.shape[0])
    if mask is not None:
        mask = _as_labels("mask", mask, pred.shape[0])
        pred, ref = pred[mask], ref[mask]
    tp = int(np.count_nonzero(pred & ref))
    fp = int(np.count_nonzero(pred & ~ref))
    fn = int(np.count_nonzero(~pred & ref))
    return tp, fp, fn, int(pred.shape[0]) - tp - fp - fn


def _kappa(tp: int, fp: int, fn: int, tn: int) -> float:
    n = tp + fp + fn + tn
    chance = (tp + fp) * (tp + fn) + (fn + tn) * (fp + tn)      # n**2 * p_e, exact
    den = n * n - chance
    if den == 0:                                                  # p_e = 1 (or n = 0)
        return 1.0 if fp + fn == 0 else 0.0
    return (n * (tp + tn) - chance) / den


def metrics_from_confusion(tp: int, fp: int, fn: int, tn: int) -> dict:
    """The point metrics of `point_metrics` from confusion counts (see the module docstring)."""
    n = tp + fp + fn + tn
    return {
        "oa": _ratio(tp + tn, n, 1.0),
        "total_error": _ratio(fp + fn, n, 0.0),
        "type1": _ratio(fn, tp + fn, 0.0),
        "type2": _ratio(fp, fp + tn, 0.0),
        "kappa": _kappa(tp, fp, fn, tn),
        "f1": _ratio(2 * tp, 2 * tp + fp + fn, 1.0),
        "iou_ground": _ratio(tp, tp + fp + fn, 1.0),
        "iou_nonground": _ratio(tn, tn + fp + fn, 1.0),
        "n_points": n, "tp": tp, "fp": fp, "fn": fn, "tn": tn,
    }


def scored_mask(classification) -> np.ndarray:
    """Points a score counts, bool `(n,)`: those whose class (uint8 `(n,)`) is not in
    `UNSCORED_CLASSES`."""
    return ~np.isin(np.asarray(classification), UNSCORED_CLASSES)


def point_metrics(pred_ground, ref_ground, mask=None) -> dict:
    """Point-wise accuracy of a ground classification (SPEC section 8).

    Args:
      pred_ground: predicted ground, bool `(n,)`.
      ref_ground: reference ground, bool `(n,)` (ISPRS: `classification == 2`).
      mask: points to score, bool `(n,)` (default: all).

    Returns:
      dict with exactly the keys `POINT_KEYS`: `oa, total_error, type1, type2, kappa, f1,
      iou_ground, iou_nonground` (floats, fractions in [0, 1]; kappa in [-1, 1]) and
      `n_points, tp, fp, fn, tn` (ints). Conventions for 0/0 in the module docstring.
    """
    return metrics_from_confusion(*confusion(pred_ground, ref_ground, mask))


def _cell_means(xy_idx: np.ndarray, z: np.ndarray, sel: np.ndarray, n_cells: int):
    count = np.bincount(xy_idx[sel], minlength=n_cells)
    total = np.bincount(xy_idx[sel], weights=z[sel], minlength=n_cells)
    valid = count > 0
    mean = np.zeros(n_cells, dtype=np.float64)
    mean[valid] = total[valid] / count[valid]
    return mean, valid


def dtm_metrics(xyz, pred_ground, ref_ground, *, cell_m: float = 2.0, mask=None) -> dict:
    """Compare cell-mean DTMs of predicted and reference ground (Wu et al. 2025, Sec. 3.1).

    Both DTMs share one grid of `cell_m` cells snapped to whole multiples of `cell_m`; a
    cell's value is the mean z of the ground points in it; cells without ground stay empty
    (no gap filling).

    Args:
      xyz: coordinates in metres, float `(n, 3)` (pass `cloud.xyz_m`).
      pred_ground, ref_ground: bool `(n,)`.
      cell_m: cell size in metres (2 m in the papers).
      mask: points to use, bool `(n,)` (default: all).

    Returns:
      dict with the keys `DTM_KEYS`:
      `rmse_m`, `mean_diff_m`: RMSE and mean of `pred - ref` over cells valid in both
        (Eq. 12, 13), metres;
      `r_o`: share of reference cells empty in the prediction (omitted ground), 0 when the
        reference has no cell;
      `r_m`: share of predicted cells empty in the reference (misidentified ground), 0 when the
        prediction has no cell;
      `share_lt_1m, share_1_2m, share_2_3m, share_ge_3m`: shares of cells valid in both with
        |difference| in [0, 1), [1, 2), [2, 3), [3, inf) m;
      `n_cells_both`: int. When it is 0, `rmse_m`, `mean_diff_m` and the four shares are NaN:
        there is nothing to compare, and 0 would read as a perfect score.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(f"xyz must have shape (n, 3), got {xyz.shape}")
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise InputError(f"cell_m must be > 0, got {cell_m}")
    n = xyz.shape[0]
    pred = _as_labels("pred_ground", pred_ground, n)
    ref = _as_labels("ref_ground", ref_ground, n)
    use = np.ones(n, dtype=bool) if mask is None else _as_labels("mask", mask, n)
    scored = use & (pred | ref)
    if np.any(scored):
        ij = np.floor(xyz[scored, :2] / cell_m).astype(np.int64)
        ij -= ij.min(axis=0)
        width = int(ij[:, 0].max()) + 1
        idx = np.zeros(n, dtype=np.int64)
        idx[scored] = ij[:, 1] * width + ij[:, 0]
        n_cells = int(idx.max()) + 1
    else:
        idx, n_cells = np.zeros(n, dtype=np.int64), 1
    z_pred, v_pred = _cell_means(idx, xyz[:, 2], use & pred, n_cells)
    z_ref, v_ref = _cell_means(idx, xyz[:, 2], use & ref, n_cells)
    both = v_pred & v_ref
    n_both = int(np.count_nonzero(both))
    diff = z_pred[both] - z_ref[both]
    out = {
        "r_o": _ratio(int(np.count_nonzero(v_ref & ~v_pred)), int(np.count_nonzero(v_ref)), 0.0),
        "r_m": _ratio(int(np.count_nonzero(v_pred & ~v_ref)), int(np.count_nonzero(v_pred)), 0.0),
        "n_cells_both": n_both,
    }
    if n_both == 0:
        nan = float("nan")
        out.update(rmse_m=nan, mean_diff_m=nan, share_lt_1m=nan, share_1_2m=nan,
                   share_2_3m=nan, share_ge_3m=nan)
    else:
        adiff = np.abs(diff)
        out.update(
            rmse_m=float(np.sqrt(np.mean(diff * diff))),
            mean_diff_m=float(np.mean(diff)),
            share_lt_1m=float(np.count_nonzero(adiff < 1.0) / n_both),
            share_1_2m=float(np.count_nonzero((adiff >= 1.0) & (adiff < 2.0)) / n_both),
            share_2_3m=float(np.count_nonzero((adiff >= 2.0) & (adiff < 3.0)) / n_both),
            share_ge_3m=float(np.count_nonzero(adiff >= 3.0) / n_both),
        )
    return {k: out[k] for k in DTM_KEYS}


def mean_over_samples(per_sample: list[dict]) -> dict:
    """Unweighted mean of per-sample figures, key by key (the papers' convention).

    Every dict must have the same keys. Counts (`tp`, `n_points`, ...) are averaged too. A NaN
    in one sample (e.g. `rmse_m` of a sample without common cells) makes that key's mean NaN,
    so a missing figure is never hidden.
    """
    if not per_sample:
        raise InputError("mean_over_samples needs at least one sample")
    keys = list(per_sample[0])
    for i, d in enumerate(per_sample):
        if set(d) != set(keys):
            raise InputError(f"sample {i} has keys {sorted(d)}, expected {sorted(keys)}")
    return {k: float(np.mean([float(d[k]) for d in per_sample])) for k in keys}


class SoftConfusion(NamedTuple):
    """Expected confusion counts under independent per-point ground probabilities (floats)."""

    tp: Float[Array, ""]
    fp: Float[Array, ""]
    fn: Float[Array, ""]
    tn: Float[Array, ""]


def soft_confusion(prob_ground: Float[ArrayLike, " n"], ref_ground: Bool[ArrayLike, " n"],
                   valid: Bool[ArrayLike, " n"]) -> SoftConfusion:
    """Expected confusion counts, differentiable in `prob_ground` (for `gfjax.tune`).

    Args:
      prob_ground: probability that each point is ground, float `(n,)` in [0, 1] (a relaxed
        threshold test, SPEC section 7). With 0/1 values the counts equal `confusion`.
      ref_ground: reference ground, bool `(n,)`.
      valid: points that count (padding and ignored points False), bool `(n,)`.

    Returns:
      `SoftConfusion(tp, fp, fn, tn)`, scalars of `prob_ground`'s dtype. Jit- and vmap-able.
    """
    if prob_ground.shape != ref_ground.shape or prob_ground.shape != valid.shape:
        raise ValueError(f"shapes differ: prob_ground {prob_ground.shape}, "
                         f"ref_ground {ref_ground.shape}, valid {valid.shape}")
    dtype = prob_ground.dtype
    zero = jnp.zeros((), dtype)
    p = jnp.where(valid, prob_ground, zero)                 # P(ground), 0 off `valid`
    q = jnp.where(valid, 1 - prob_ground, zero)             # P(object), 0 off `valid`
    r = ref_ground.astype(dtype)
    tp = jnp.sum(p * r)
    fp = jnp.sum(p * (1 - r))
    fn = jnp.sum(q * r)
    tn = jnp.sum(q * (1 - r))
    return SoftConfusion(tp, fp, fn, tn)


def expected_total_error(c: SoftConfusion) -> Float[Array, ""]:
    """`(fp + fn) / n` of a soft confusion; 0 when `n == 0`. Differentiable."""
    n = c.tp + c.fp + c.fn + c.tn
    safe_n = jnp.where(n > 0, n, jnp.ones_like(n))
    return jnp.where(n > 0, (c.fp + c.fn) / safe_n, jnp.zeros_like(n))


def soft_kappa(c: SoftConfusion) -> Float[Array, ""]:
    """Cohen's kappa of a soft confusion, same formula and `p_e = 1` convention as `kappa`.

    Computed on fractions of `n` (float32 cannot hold `n**2` exactly). Differentiable; the
    safe divisions keep gradients finite where `p_e = 1` or `n = 0`.
    """
    n = c.tp + c.fp + c.fn + c.tn
    safe_n = jnp.where(n > 0, n, jnp.ones_like(n))
    tp, fp, fn, tn = (x / safe_n for x in c)                # fractions: no n**2 in float32
    chance = (tp + fp) * (tp + fn) + (fn + tn) * (fp + tn)  # p_e
    den = 1 - chance
    ok = (den > 0) & (n > 0)
    safe_den = jnp.where(ok, den, jnp.ones_like(den))
    agree = jnp.where(fp + fn > 0, jnp.zeros_like(n), jnp.ones_like(n))
    return jnp.where(ok, (tp + tn - chance) / safe_den, agree)


__all__ = ["UNSCORED_CLASSES", "POINT_KEYS", "DTM_KEYS", "scored_mask", "confusion", "point_metrics", "metrics_from_confusion",
           "dtm_metrics", "mean_over_samples", "SoftConfusion", "soft_confusion",
           "expected_total_error", "soft_kappa"]
