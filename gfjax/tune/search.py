"""Tuning by exhaustive search over a finite set of candidates, under the same guard as the
gradient fits (`gfjax.tune.guard`).

Some methods' thresholds reach the labels only through host code with no gradient: MASF's
TIN densification runs on scipy triangulations, and its alpha pyramid changes which points
exist in each layer. For them, `gfjax tune` labels every labelled sample once with each
candidate setting (a grid, `gfjax.tune.masf.GRID`), keeps which points each candidate gets
wrong, and chooses among the candidates from those tables alone. Every protocol (a fold, a
training half, all labels) is then a choice over the same tables: a grid search needs no
re-run of the filter per fold.

The guard is `gfjax.tune.guard`'s rule with one level instead of three: units (samples when a
group has two or more, else square spatial blocks, `guard.fold_plan`) are dealt to folds; for
each fold the candidate of lowest weighted total error on the other folds is scored against
the defaults on the held-out points; every unit is held out once and gets its out-of-fold gain
(net point errors fixed, times the sample's weight over its labelled points); the sum is tested
against "no gain" by the one-sided sign-flip test (`guard.sign_flip_p`). The best candidate on
all labelled points is kept only when the summed gain is positive and p < `alpha`; otherwise
the defaults are. Choosing the best of many candidates on the training folds is part of each
fold's fit, so the out-of-fold gain already pays for it: no multiplicity factor.
"""
from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import NamedTuple

import numpy as np

from gfjax import aot
from gfjax.tune.guard import fold_plan, sign_flip_p
from gfjax.tune.problem import Sample

__all__ = ["Choice", "Searched", "Tuned", "errors", "grid_candidates", "validate", "wrong_table"]


class Choice(NamedTuple):
    """Outcome of `validate`.

    Attributes:
      index: the candidate to use (`default` where the fit was not kept).
      best: the candidate of lowest weighted total error on every labelled point.
      kept: whether the guard kept `best`.
      default_error, tuned_error: out-of-fold weighted total error of the defaults and of each
        fold's choice (every labelled point held out once); training errors without folds.
      p_value: the sign-flip p-value (nan without folds).
      units: validation units whose gain is not zero.
      by_sample: units are samples (else spatial blocks).
      fold_errors: float64 `(folds, 2)` held-out error (defaults, choice) per fold.
      train_errors: float64 `(c,)` weighted total error of each candidate on every labelled point.
    """

    index: int
    best: int
    kept: bool
    default_error: float
    tuned_error: float
    p_value: float
    units: int
    by_sample: bool
    fold_errors: np.ndarray
    train_errors: np.ndarray


def errors(wrong: list[np.ndarray], masks: list[np.ndarray], weight: np.ndarray) -> np.ndarray:
    """float64 `(c,)`: each candidate's total error over the points of `masks`, summed over
    samples with `weight` (`wrong[i]`: bool `(c, n_i)` points candidate c mislabels)."""
    total = np.zeros(wrong[0].shape[0])
    for w, m, s in zip(wrong, masks, weight):
        count = int(m.sum())
        if count and s > 0:
            total += s * w[:, m].sum(axis=1) / count
    return total


def _choose(err: np.ndarray, default: int) -> int:
    """The candidate of lowest error; the defaults on a tie (a fit must earn its change)."""
    best = int(np.argmin(err))
    return default if err[default] <= err[best] else best


def validate(wrong: list[np.ndarray], xyzs: list[np.ndarray], masks: list[np.ndarray], *, default: int,
             weight: np.ndarray | None = None, folds: int = 3, block_m: float = 50.0, alpha: float = 0.05,
             seed: int = 0) -> Choice:
    """Choose a candidate, and keep it only where cross-validation and a sign-flip test say it
    beats the defaults (module docstring).

    Args:
      wrong: per sample bool `(c, n_i)`, the points each candidate mislabels.
      xyzs: per sample float `(n_i, 3)` [m] (for the spatial blocks).
      masks: per sample bool `(n_i,)`, the labelled points that count.
      default: the candidate holding the method's defaults.
      weight: float `(samples,)` (default: equal, summing to 1).
      folds: cross-validation folds (>= 2), or 0 / 1 for none (the best is kept wherever it
        lowers the training error).
      block_m: side of the blocks of a single sample [m].
      alpha: level of the test, in (0, 1).
      seed: of the folds and of the randomised test.
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    n_samples = len(wrong)
    weight = np.full(n_samples, 1.0 / n_samples) if weight is None else np.asarray(weight, np.float64)
    masks = [np.asarray(m, bool) for m in masks]
    train_errors = errors(wrong, masks, weight)
    best = _choose(train_errors, default)
    if folds < 2:
        kept = bool(train_errors[best] < train_errors[default])
        return Choice(best if kept else default, best, kept, float(train_errors[default]), float(train_errors[best]),
                      float("nan"), 0, False, np.zeros((0, 2)), train_errors)

    group = np.zeros(n_samples, np.int32)
    by_sample, fold_id, unit_id, n_units = fold_plan(xyzs, group, weight, folds, block_m, seed)
    labelled = np.array([m.sum() for m in masks], np.float64)
    scale = np.where(labelled > 0, weight / np.maximum(labelled, 1), 0.0)     # per-point weight of a sample
    gains = np.zeros(n_units)
    fold_errors = np.zeros((folds, 2))
    for k in range(folds):
        train = [m & (f != k) for m, f in zip(masks, fold_id)]
        held = [m & (f == k) for m, f in zip(masks, fold_id)]
        w_k = np.where([t.any() for t in train], weight, 0.0)
        if not np.any(w_k > 0):
            continue
        w_k *= weight.sum() / w_k.sum()
        chosen = _choose(errors(wrong, train, w_k), default)
        held_n = np.array([h.sum() for h in held], np.float64)
        fold_scale = np.where(held_n > 0, weight / np.maximum(held_n, 1), 0.0)
        for i in range(n_samples):
            h = held[i]
            fixed = wrong[i][default, h].astype(np.int64) - wrong[i][chosen, h].astype(np.int64)
            np.add.at(gains, unit_id[i][h], scale[i] * fixed)
            fold_errors[k] += fold_scale[i] * np.array([wrong[i][default, h].sum(), wrong[i][chosen, h].sum()])
    default_error = float(train_errors[default])
    p_value = sign_flip_p(gains, seed=seed)
    kept = bool(gains.sum() > 0 and p_value < alpha and best != default)
    return Choice(best if kept else default, best, kept, default_error, default_error - float(gains.sum()),
                  p_value, int(np.count_nonzero(gains)), bool(by_sample[0]), fold_errors, train_errors)


def grid_candidates(defaults: Mapping[str, float], grid: Mapping[str, Sequence[float]], *,
                    keep: Callable[[dict[str, float]], bool] | None = None) -> tuple[list[dict[str, float]], int]:
    """Every combination of `grid` (each key's values, with its default added where missing),
    in the key order of `defaults`, less those `keep` rejects; and the index of the defaults'."""
    if set(grid) != set(defaults):
        raise ValueError(f"the grid must set {', '.join(defaults)}, got {', '.join(grid)}")
    axes = {k: tuple(sorted({float(v) for v in grid[k]} | {float(defaults[k])})) for k in defaults}
    combos = [dict(zip(axes, values)) for values in itertools.product(*axes.values())]
    combos = [c for c in combos if keep is None or keep(c)]
    return combos, combos.index({k: float(v) for k, v in defaults.items()})


class Tuned(NamedTuple):
    """Outcome of `tune`: `values` to write to params.json (the defaults unless the guard kept
    the fit), `combos` (every candidate), `default` (the defaults' index), `choice`
    (`Choice`), `wrong` (per sample, the tables the choice was made from)."""

    values: dict[str, float]
    combos: list[dict[str, float]]
    default: int
    choice: Choice
    wrong: list[np.ndarray]


def wrong_table(labels: Iterator[np.ndarray], sample: Sample, n_combos: int, *, bar=None) -> np.ndarray:
    """bool `(c, n)`: where each of the `n_combos` label arrays `labels` yields (bool `(n,)`,
    the filter's ground for each candidate in turn) disagrees with `sample.ref_ground`. `bar`:
    a tqdm bar advanced once per candidate."""
    wrong = np.empty((n_combos, len(sample.xyz_m)), bool)
    for row, ground in enumerate(labels):
        wrong[row] = ground != sample.ref_ground
        if bar is not None:
            bar.update(1)
    return wrong


@dataclasses.dataclass(frozen=True)
class Searched:
    """A method tuned by grid search (`gfjax.tune.masf.METHOD`, `gfjax.tune.dmf.METHOD`).

    Attributes:
      name: the method's name in `gfjax.methods` and params.json.
      config_type: its `Config` class.
      default_grid: `(config) -> {key: values}`, the grid `gfjax tune` searches by default.
      candidates: `(config, grid or None) -> (combinations, index of the defaults')`.
      labels: `(sample, config, combinations)` -> an iterator of the filter's ground (bool
        `(n,)`) with each combination in turn, from the filter's own stages.
      units: unit of every key written to params.json.
      note: why the keys are searched, not fitted by gradient (params.json).
    """

    name: str
    config_type: type
    default_grid: Callable
    candidates: Callable
    labels: Callable
    units: Mapping[str, str]
    note: str

    def wrong_table(self, sample: Sample, config, combos: Sequence[Mapping[str, float]], *, bar=None) -> np.ndarray:
        """bool `(c, n)`: the points of `sample` the method with each combination mislabels.
        The programs its candidates compiled are released afterwards (`gfjax.aot.release`):
        a grid over static settings compiles many shapes, and each holds memory maps."""
        try:
            return wrong_table(self.labels(sample, config, combos), sample, len(combos), bar=bar)
        finally:
            aot.release()

    def tune(self, samples: Sequence[Sample], *, config=None, grid: Mapping[str, Sequence[float]] | None = None,
             masks: Sequence[np.ndarray] | None = None, folds: int = 3, block_m: float = 50.0, alpha: float = 0.05,
             seed: int = 0, progress: bool = False) -> Tuned:
        """One setting for labelled `samples`: every candidate of `grid` (default
        `default_grid`) labels every sample, and `validate` chooses (equal weight per sample;
        `masks`: the labelled points that count, default every used point)."""
        config = self.config_type() if config is None else config
        combos, default = self.candidates(config, grid)
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=len(combos) * len(samples), desc=f"{self.name} grid", unit="run", leave=False)
        try:
            wrong = [self.wrong_table(s, config, combos, bar=bar) for s in samples]
        finally:
            if bar is not None:
                bar.close()
        masks = ([s.use for s in samples] if masks is None
                 else [np.asarray(m, bool) & s.use for m, s in zip(masks, samples)])
        choice = validate(wrong, [s.xyz_m for s in samples], masks, default=default, folds=folds, block_m=block_m,
                          alpha=alpha, seed=seed)
        return Tuned(dict(combos[choice.index]), combos, default, choice, wrong)
