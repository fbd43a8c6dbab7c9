"""The out-of-sample guard of `gfjax tune`: keep a fit only where held-out labels
say, with statistical confidence, that it beats the defaults.

Tuned thresholds often do worse than the defaults on data they were not fitted to (on the
ISPRS samples a fit to one half of a sample, or to other samples, was worse on
average). `validate` therefore decides per parameter group g, on the group's labelled
points only, by cross-validation and a paired test:

1. Validation units. A group with two or more samples of positive weight is validated by
   *sample* (units = samples, dealt to `folds` folds): between-sample transfer is what must
   hold. A group of one sample is validated by *spatial block* (units = square blocks of
   `block_m`, dealt to `folds` folds, `problem.block_folds`): neighbouring points share
   errors (a missed building), so blocks, not points, are the independent units.
2. For each fold k, `fit` runs on the other folds (prior toward the defaults included) and
   gives theta_k. On the held-out points the plain filter labels them with the defaults
   D and with the shrunken values `D + a (theta_k - D)` (the fitted window) for each
   shrink level `a` of `shrink`.
3. Every unit u is held out once, so each gets an out-of-fold gain per level:
   `e_u(a) = w_s (E_u(D) - E_u(a)) / N_s`, the net number of point errors fixed in u,
   times the sample's weight over its labelled points (the sum over units is the drop of
   the group's weighted total error).
4. The level with the largest summed gain is chosen, and tested against "no gain" with a
   one-sided sign-flip (randomisation) test over the units with `e_u != 0`: the p-value is
   the share of sign patterns s with `sum s_u |e_u| >= sum e_u` (exact up to 16 units,
   else 2^14 seeded draws), multiplied by the number of levels (Bonferroni for choosing
   the level). With one point per unit this is McNemar's exact test; with blocks it is its
   cluster-robust form.
5. The group keeps `D + a* (theta - D)`, theta and its window fitted on all its labelled
   points, only when the summed gain is positive and the adjusted p-value is below `alpha`
   (default 0.05); else it keeps the defaults. No other rule is used: in particular the
   training error is never consulted. With the 3 default levels, fewer than 6 non-zero
   units can never pass at 0.05 (3 x 2^-5 = 0.094): small labelled sets keep the defaults.

`folds < 2` skips validation: the fit is kept wherever it lowered the training objective.
"""
from __future__ import annotations

import itertools
from typing import NamedTuple

import numpy as np

from gfjax.tune import fit as tfit
from gfjax.tune.problem import Problem, block_folds, block_ids

__all__ = ["Validation", "validate", "sign_flip_p", "fold_plan", "SHRINK"]

SHRINK = (1 / 3, 2 / 3, 1.0)   # points on the segment defaults -> fit that validation compares
_EXACT_UNITS = 16
_DRAWS = 1 << 14


class Validation(NamedTuple):
    """Outcome of `validate`, per group g.

    Attributes:
      values: float32 `(g, 3)` thresholds to use (ordered as `problem.method.bounds`).
      window_m: float64 `(g,)` window to use (the default window where not kept).
      kept: bool `(g,)` whether the test said the (shrunken) fit beats the defaults.
      shrink: float64 `(g,)` chosen level a* on the segment defaults -> fit (0 where not kept).
      default_error, tuned_error: float64 `(g,)` out-of-fold weighted total error of the
        defaults and of the chosen level (every labelled point held out once).
      p_value: float64 `(g,)` Bonferroni-adjusted sign-flip p-value of the chosen level.
      units: int `(g,)` validation units with a non-zero gain (the test's sample size).
      by_sample: bool `(g,)` units are samples (else spatial blocks).
      fold_errors: float64 `(folds, g, 2)` held-out error (defaults, chosen level) per fold.
      fit: `FitResult` of the final fit on all labelled points; None when nothing was kept
        (the final fit is skipped).
      hard_evaluations, gradient_calls: summed over all fits and evaluations.
    """

    values: np.ndarray
    window_m: np.ndarray
    kept: np.ndarray
    shrink: np.ndarray
    default_error: np.ndarray
    tuned_error: np.ndarray
    p_value: np.ndarray
    units: np.ndarray
    by_sample: np.ndarray
    fold_errors: np.ndarray
    fit: tfit.FitResult | None
    hard_evaluations: int
    gradient_calls: int


def sign_flip_p(gains: np.ndarray, *, seed: int = 0) -> float:
    """One-sided sign-flip p-value of `sum(gains) > 0` (float64 `(u,)` per-unit gains).

    Zero gains are dropped; exact enumeration of the `2^u` sign patterns up to 16 units,
    else `2^14` seeded random patterns (p = (1 + hits) / (1 + draws)). 1.0 with no units.
    """
    e = np.asarray(gains, np.float64)
    e = e[e != 0]
    if e.size == 0:
        return 1.0
    observed = e.sum()
    size = np.abs(e)
    tol = 1e-12 * size.sum()
    if e.size <= _EXACT_UNITS:
        signs = np.asarray(list(itertools.product((-1.0, 1.0), repeat=e.size)))
        return float(np.mean(signs @ size >= observed - tol))
    rng = np.random.default_rng(seed)
    signs = rng.choice(np.asarray([-1.0, 1.0]), size=(_DRAWS, e.size))
    return float((1 + np.sum(signs @ size >= observed - tol)) / (1 + _DRAWS))


def fold_plan(xyzs: list[np.ndarray], group: np.ndarray, weight: np.ndarray, folds: int, block_m: float,
              seed: int) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray], int]:
    """The validation units and folds of samples `xyzs` (each float `(n_i, 3)` [m]; rule 1 of
    the module docstring).

    Returns:
      `(by_sample (g,) bool, fold id per point of each sample (-1: never held out), unit id per
      point of each sample (global: samples first, then blocks), number of units)`.
    """
    n_samples = len(xyzs)
    n_groups = int(group.max()) + 1
    positive = weight > 0
    by_sample = np.bincount(group[positive], minlength=n_groups) >= 2
    rng = np.random.default_rng(seed)
    fold_of_sample = np.full(n_samples, -1)
    for g in np.flatnonzero(by_sample):
        members = rng.permutation(np.flatnonzero((group == g) & positive))
        fold_of_sample[members] = np.arange(members.size) % min(folds, members.size)
    fold_id, unit_id = [], []
    offset = n_samples                               # units 0..c-1 are whole samples
    for i, xyz_m in enumerate(xyzs):
        n = len(xyz_m)
        if by_sample[group[i]]:
            fold_id.append(np.full(n, fold_of_sample[i]))
            unit_id.append(np.full(n, i, np.int64))
        elif not positive[i]:
            fold_id.append(np.full(n, -1))
            unit_id.append(np.full(n, i, np.int64))
        else:
            fold_id.append(block_folds(xyz_m, folds=folds, block_m=block_m, seed=seed + i))
            blocks = block_ids(xyz_m, block_m=block_m)
            unit_id.append(offset + blocks)
            offset += int(blocks.max(initial=-1)) + 1
    return by_sample, fold_id, unit_id, offset


def _wrong(problem: Problem, values, window_m, group) -> list[np.ndarray]:
    """Per sample bool `(n,)`: points the plain filter mislabels with per-group values/windows."""
    wrong = [np.zeros(len(s.xyz_m), bool) for s in problem.samples]
    for w in np.unique(window_m):
        labels = problem.labels(tfit.hard_ground(problem, values, group, float(w)))
        for i, s in enumerate(problem.samples):
            if window_m[group[i]] == w:
                wrong[i] = labels[i] != s.ref_ground
    return wrong


def validate(problem: Problem, settings: tfit.Settings = tfit.Settings(), *, point_masks=None, group=None,
             weight=None, folds: int = 3, block_m: float = 50.0, shrink: tuple[float, ...] = SHRINK,
             alpha: float = 0.05, seed: int = 0, progress: bool = False) -> Validation:
    """Fit, and keep the fit only where cross-validation and a sign-flip test say it helps.

    Args:
      problem: the prepared samples.
      settings: of each `fit`.
      point_masks: per sample bool `(n,)`: the labelled points to use (default all).
      group: int `(c,)` parameter group per sample (default one group).
      weight: float `(c,)` per-sample weight (default 1 / samples per group).
      folds: cross-validation folds (>= 2), or 0 / 1 for no validation.
      block_m: side of the validation blocks of one-sample groups [m].
      shrink: levels a in (0, 1] on the segment defaults -> fit.
      alpha: test level (after the Bonferroni factor `len(shrink)`).
      seed: of the fold assignment and the randomised test.
      progress: tqdm bars of the fits.

    Returns:
      A `Validation` (rule: module docstring).
    """
    if not shrink or any(not 0 < a <= 1 for a in shrink):
        raise ValueError(f"shrink levels must lie in (0, 1], got {shrink}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    c = problem.n_samples
    group = np.zeros(c, np.int32) if group is None else np.asarray(group, np.int32)
    n_groups = int(group.max()) + 1
    if weight is None:
        weight = 1.0 / np.bincount(group, minlength=n_groups)[group]
    weight = np.asarray(weight, np.float64)
    covered = problem.covered()
    base = covered if point_masks is None else [np.asarray(m, bool) & cv for m, cv in zip(point_masks, covered)]
    defaults = np.tile(problem.defaults, (n_groups, 1))
    default_window = np.full(n_groups, problem.method.default_static(problem.config))
    passes = grads = 0
    n_levels = len(shrink)
    if folds < 2:
        final = tfit.fit(problem, settings, masks=problem.masks(base), group=group, weight=weight, progress=progress)
        kept = final.train_error < final.start_error
        return Validation(np.where(kept[:, None], final.values, defaults).astype(np.float32),
                          np.where(kept, final.window_m, default_window), kept, kept.astype(np.float64),
                          final.start_error, final.train_error, np.full(n_groups, np.nan),
                          np.zeros(n_groups, int), np.zeros(n_groups, bool), np.zeros((0, n_groups, 2)), final,
                          final.hard_evaluations, final.gradient_calls)

    by_sample, fold_id, unit_id, n_units = fold_plan([s.xyz_m for s in problem.samples], group, weight, folds,
                                                     block_m, seed)
    n_points = np.array([m.sum() for m in base], np.float64)
    scale = np.where(n_points > 0, weight / np.maximum(n_points, 1), 0.0)     # per-point weight of a sample
    wrong_default = _wrong(problem, defaults, default_window, group)
    passes += 1
    gains = np.zeros((n_levels, n_units))
    fold_errors = np.zeros((folds, n_groups, 1 + n_levels))
    for k in range(folds):
        train = [b & (f != k) for b, f in zip(base, fold_id)]
        held = [b & (f == k) for b, f in zip(base, fold_id)]
        w_k = np.where([t.any() for t in train], weight, 0.0)
        if not np.any(w_k > 0):
            continue
        totals = np.bincount(group, weight, minlength=n_groups), np.bincount(group, w_k, minlength=n_groups)
        w_k = w_k * np.where(totals[1] > 0, totals[0] / np.maximum(totals[1], 1e-300), 0.0)[group]   # group sums kept
        result = tfit.fit(problem, settings, masks=problem.masks(train), group=group, weight=w_k, progress=progress)
        passes += result.hard_evaluations
        grads += result.gradient_calls
        held_n = np.array([h.sum() for h in held], np.float64)
        fold_scale = np.where(held_n > 0, weight / np.maximum(held_n, 1), 0.0)
        for i in range(c):
            fold_errors[k, group[i], 0] += fold_scale[i] * np.sum(wrong_default[i][held[i]])
        for j, a in enumerate(shrink):
            values = (defaults + a * (result.values - defaults)).astype(np.float32)
            wrong = _wrong(problem, values, result.window_m, group)
            passes += len(np.unique(result.window_m))
            for i in range(c):
                h = held[i]
                fixed = wrong_default[i][h].astype(np.int64) - wrong[i][h].astype(np.int64)
                np.add.at(gains[j], unit_id[i][h], scale[i] * fixed)
                fold_errors[k, group[i], 1 + j] += fold_scale[i] * np.sum(wrong[i][h])

    unit_group = np.full(n_units, -1)
    for i in range(c):
        unit_group[unit_id[i][base[i]]] = group[i]
    default_error = np.zeros(n_groups)
    for i in range(c):
        default_error[group[i]] += scale[i] * np.sum(wrong_default[i][base[i]])
    kept = np.zeros(n_groups, bool)
    level = np.zeros(n_groups, int)
    p_value = np.ones(n_groups)
    units = np.zeros(n_groups, int)
    tuned_error = default_error.copy()
    for g in range(n_groups):
        gain_g = gains[:, unit_group == g]                                      # (levels, units of g)
        level[g] = int(np.argmax(gain_g.sum(axis=1)))
        best = gain_g[level[g]]
        units[g] = int(np.count_nonzero(best))
        p_value[g] = min(1.0, n_levels * sign_flip_p(best, seed=seed + g))
        tuned_error[g] = default_error[g] - best.sum()
        kept[g] = best.sum() > 0 and p_value[g] < alpha
    chosen = np.asarray(shrink, np.float64)[level]
    per_fold = np.stack([fold_errors[:, :, 0], fold_errors[np.arange(folds)[:, None], np.arange(n_groups), 1 + level]],
                        axis=-1)
    if not kept.any():
        return Validation(defaults.astype(np.float32), default_window, kept, np.zeros(n_groups), default_error,
                          tuned_error, p_value, units, by_sample, per_fold, None, passes, grads)
    final = tfit.fit(problem, settings, masks=problem.masks(base), group=group, weight=weight, progress=progress)
    passes += final.hard_evaluations
    grads += final.gradient_calls
    shrunk = defaults + chosen[:, None] * (final.values - defaults)
    values = np.where(kept[:, None], shrunk, defaults).astype(np.float32)
    window = np.where(kept, final.window_m, default_window)
    return Validation(values, window, kept, np.where(kept, chosen, 0.0), default_error, tuned_error, p_value,
                      units, by_sample, per_fold, final, passes, grads)
