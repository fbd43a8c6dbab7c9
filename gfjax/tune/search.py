"""Tuning by exhaustive search over a finite set of candidates, under the same guard as the
gradient fits (`gfjax.tune.guard`).

Some methods' thresholds reach the labels only through host code with no gradient: MASF's
TIN densification runs on scipy triangulations, and its alpha pyramid changes which points
exist in each layer. For them, `gfjax tune` labels every labelled sample once with each
candidate setting (a grid, `gfjax.masf.tuning.GRID`), keeps which points each candidate gets
wrong, and chooses among the candidates from those tables alone. Every protocol (a fold, a
training half, all labels) is then a choice over the same tables: a grid search needs no
re-run of the filter per fold.

A guarded choice is made by the one-standard-error rule (Breiman et al. 1984; Hastie,
Tibshirani & Friedman 2009, Sec. 7.10), with the defaults as the simplest model: among the
candidates whose weighted total error exceeds the lowest by at most one standard error of
that difference (over the validation units, below) plus `TIE_MARGIN`, the one fewest grid
steps from the defaults (`grid_distance`; then the lowest error). The lowest error of a few
hundred candidates on a few blocks is an optimistic pick: on the ISPRS halves, the plain best
candidate of one half often sat at the grid's edge and lost on the other half. The rule
shrinks toward the defaults, as the gradient fits' shrink levels do.

The margin makes differences too small to matter ties. The standard error alone can be tiny
when a few points, wrong in every block alike, separate two candidates: on the west half of
ISPRS samp42, MASF's lowest error (0.49 %, ST 0.01 and four other changes) beat the defaults
with only the 90 m top layer (0.59 %) by a tenth of a point, steadily across blocks, and then
scored 4.48 % against 1.01 % on the east half. The margin was set on those ISPRS halves
(`experiments/tune_grid.py`, its sweep of margins): with MASF, 0.1-0.2 points let a fit of
samp41's west half cost its east half 7.4 points, 0.3-0.5 points left no half of any sample
worse than the defaults, and larger margins kept fewer fits; 0.4 is the middle of that range.

The guard is `gfjax.tune.guard`'s rule with that choice in place of the fit: units (samples
when a group has two or more, else square spatial blocks, `guard.fold_plan`) are dealt to
folds; for each fold the candidate the rule picks on the other folds is scored against the
defaults on the held-out points; every unit is held out once and gets its out-of-fold gain
(net point errors fixed, times the sample's weight over its labelled points); the sum is tested
against "no gain" by the one-sided sign-flip test (`guard.sign_flip_p`). The rule's pick on
all labelled points is kept only when the summed gain is positive and p < `alpha`; otherwise
the defaults are. Choosing among many candidates on the training folds is part of each fold's
fit, so the out-of-fold gain already pays for it: no multiplicity factor.
"""
from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from gfjax import aot
from gfjax.tune.guard import fold_plan, sign_flip_p
from gfjax.tune.problem import Sample

__all__ = ["Choice", "GridTuner", "TIE_MARGIN", "Searched", "errors", "grid_candidates", "grid_distance", "one_se_choice",
           "unit_errors", "validate", "wrong_table"]


class Choice(NamedTuple):
    """Outcome of `validate`.

    Attributes:
      index: the candidate to use (`default` where the fit was not kept).
      best: the candidate of lowest weighted total error on every labelled point (the plain,
        unguarded choice).
      kept: whether the guard kept the rule's pick (`index`).
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


TIE_MARGIN = 0.004   # total errors within 0.4 percentage points of the lowest (plus one standard
                     # error) are as good as the lowest: the rule then takes the one nearest the defaults
_CHUNK = 64          # candidates counted at a time by `unit_errors` (bounds its int32 copy)


def unit_errors(wrong: list[np.ndarray], masks: list[np.ndarray], weight: np.ndarray, unit_id: list[np.ndarray],
                n_units: int) -> tuple[np.ndarray, np.ndarray]:
    """`errors` split by validation unit: float64 `(c, n_units)`, whose row sums are
    `errors(wrong, masks, weight)`, and bool `(n_units,)`, the units holding a point of `masks`.

    Args:
      wrong, masks, weight: as `errors`.
      unit_id: per sample int `(n_i,)`, the unit of each point (`guard.fold_plan`).
      n_units: number of units.
    """
    out = np.zeros((wrong[0].shape[0], n_units))
    present = np.zeros(n_units, bool)
    for w, m, s, unit in zip(wrong, masks, weight, unit_id):
        count = int(m.sum())
        if not count or s <= 0:
            continue
        points = np.flatnonzero(m)
        order = np.argsort(unit[points], kind="stable")
        points = points[order]                       # the labelled points, grouped by unit
        ids = unit[points]
        starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
        cols = w[:, points]
        for lo in range(0, cols.shape[0], _CHUNK):
            counts = np.add.reduceat(cols[lo:lo + _CHUNK].astype(np.int32), starts, axis=1)
            out[lo:lo + _CHUNK, ids[starts]] += s * counts / count
        present[ids[starts]] = True
    return out, present


def _lowest(err: np.ndarray, default: int) -> int:
    """The candidate of lowest error; the defaults on a tie (a fit must earn its change)."""
    best = int(np.argmin(err))
    return default if err[default] <= err[best] else best


def one_se_choice(unit_err: np.ndarray, default: int, distance: np.ndarray, *, margin: float = TIE_MARGIN) -> int:
    """The one-standard-error rule (module docstring): among the candidates whose total error
    exceeds the lowest by at most one standard error of the difference plus `margin`, the one
    with the smallest `distance` from the defaults, then the lowest error.

    Args:
      unit_err: float64 `(c, u)` each candidate's error per validation unit (`unit_errors`,
        the units holding labelled points only).
      default: the candidate holding the defaults.
      distance: `(c,)` each candidate's distance from the defaults (`grid_distance`).
      margin: differences of total error (a fraction of the labelled points) taken as ties.

    The standard error of a candidate's excess `sum_u d_u` (d_u: its error in unit u less the
    lowest candidate's) is `sqrt(u / (u - 1) * sum_u (d_u - mean d)^2)`, the units taken as
    independent; 0 with one unit (then the rule is the lowest error).
    """
    total = unit_err.sum(axis=1)
    best = _lowest(total, default)
    diff = unit_err - unit_err[best]
    u = unit_err.shape[1]
    if u > 1:
        se = np.sqrt(u / (u - 1) * np.sum((diff - diff.mean(axis=1, keepdims=True)) ** 2, axis=1))
    else:
        se = np.zeros(len(total))
    near = np.flatnonzero(total - total[best] <= se + margin + 1e-12 * max(1.0, abs(total[best])))
    pick = near[np.lexsort((total[near], np.asarray(distance)[near]))[0]]
    return default if total[default] <= total[pick] and distance[default] <= distance[pick] else int(pick)


def validate(wrong: list[np.ndarray], xyzs: list[np.ndarray], masks: list[np.ndarray], *, default: int,
             distance: np.ndarray | None = None, weight: np.ndarray | None = None, folds: int = 3,
             block_m: float = 50.0, alpha: float = 0.05, seed: int = 0, margin: float = TIE_MARGIN) -> Choice:
    """Choose a candidate by the one-standard-error rule, and keep it only where
    cross-validation and a sign-flip test say it beats the defaults (module docstring).

    Args:
      wrong: per sample bool `(c, n_i)`, the points each candidate mislabels.
      xyzs: per sample float `(n_i, 3)` [m] (for the spatial blocks).
      masks: per sample bool `(n_i,)`, the labelled points that count.
      default: the candidate holding the method's defaults.
      distance: `(c,)` each candidate's distance from the defaults (`grid_distance`; default
        0 for the defaults and 1 for every other candidate).
      weight: float `(samples,)` (default: equal, summing to 1).
      folds: cross-validation folds (>= 2), or 0 / 1 for none (then the lowest training error
        is kept wherever it lowers the defaults': no rule, no guard).
      block_m: side of the blocks of a single sample [m].
      alpha: level of the test, in (0, 1).
      seed: of the folds and of the randomised test.
      margin: differences of total error taken as ties by the rule (`one_se_choice`).
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    n_samples = len(wrong)
    n_combos = wrong[0].shape[0]
    weight = np.full(n_samples, 1.0 / n_samples) if weight is None else np.asarray(weight, np.float64)
    if distance is None:
        distance = (np.arange(n_combos) != default).astype(np.int64)
    distance = np.asarray(distance)
    if distance.shape != (n_combos,):
        raise ValueError(f"distance needs one entry per candidate ({n_combos}), got shape {distance.shape}")
    masks = [np.asarray(m, bool) for m in masks]
    train_errors = errors(wrong, masks, weight)
    best = _lowest(train_errors, default)
    if folds < 2:
        kept = bool(train_errors[best] < train_errors[default])
        return Choice(best if kept else default, best, kept, float(train_errors[default]), float(train_errors[best]),
                      float("nan"), 0, False, np.zeros((0, 2)), train_errors)

    group = np.zeros(n_samples, np.int32)
    by_sample, fold_id, unit_id, n_units = fold_plan(xyzs, group, weight, folds, block_m, seed)

    def rule(ms: list[np.ndarray], w: np.ndarray) -> int:
        per_unit, present = unit_errors(wrong, ms, w, unit_id, n_units)
        return one_se_choice(per_unit[:, present], default, distance, margin=margin)

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
        chosen = rule(train, w_k)
        held_n = np.array([h.sum() for h in held], np.float64)
        fold_scale = np.where(held_n > 0, weight / np.maximum(held_n, 1), 0.0)
        for i in range(n_samples):
            h = held[i]
            fixed = wrong[i][default, h].astype(np.int64) - wrong[i][chosen, h].astype(np.int64)
            np.add.at(gains, unit_id[i][h], scale[i] * fixed)
            fold_errors[k] += fold_scale[i] * np.array([wrong[i][default, h].sum(), wrong[i][chosen, h].sum()])
    default_error = float(train_errors[default])
    p_value = sign_flip_p(gains, seed=seed)
    pick = rule(masks, weight)
    kept = bool(gains.sum() > 0 and p_value < alpha and pick != default)
    return Choice(pick if kept else default, best, kept, default_error, default_error - float(gains.sum()),
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


def grid_distance(combos: Sequence[Mapping[str, float]], default: int) -> np.ndarray:
    """int64 `(c,)`: how many grid steps each candidate lies from the defaults' (per key, the
    distance between their positions among the key's sorted values, summed over keys)."""
    out = np.zeros(len(combos), np.int64)
    for key in combos[default]:
        axis = sorted({float(c[key]) for c in combos})
        rank = np.searchsorted(axis, [float(c[key]) for c in combos])
        out += np.abs(rank - rank[default])
    return out


class Searched(NamedTuple):
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
class GridTuner:
    """A method tuned by grid search (`gfjax.masf.tuning.TUNER`, `gfjax.dmf.tuning.TUNER`).

    Attributes:
      name: the method's name in `gfjax.methods` and params.json.
      config_type: its `Config` class.
      default_grid: `(config) -> {key: values}`, the grid `gfjax tune` searches by default.
      candidates: `(config, grid or None) -> (combinations, index of the defaults')`.
      labels: `(sample, config, combinations)` -> an iterator of the filter's ground (bool
        `(n,)`) with each combination in turn, from the filter's own stages.
      units: unit of every key written to params.json.
      note: why the keys are searched, not fitted by gradient (params.json).
      values: `(combination) -> params.json values` (default: the combination as it is).
      grid_ranges: valid values of a grid key where they differ from the method's `RANGES`
        (a grid may encode "none" as a number).
    """

    name: str
    config_type: type
    default_grid: Callable
    candidates: Callable
    labels: Callable
    units: Mapping[str, str]
    note: str
    values: Callable[[Mapping[str, float]], dict[str, float]] = dict
    grid_ranges: Mapping[str, Any] = dataclasses.field(default_factory=dict)

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
             seed: int = 0, progress: bool = False) -> Searched:
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
        choice = validate(wrong, [s.xyz_m for s in samples], masks, default=default,
                          distance=grid_distance(combos, default), folds=folds, block_m=block_m,
                          alpha=alpha, seed=seed)
        return Searched(self.values(combos[choice.index]), combos, default, choice, wrong)
