"""The optax loop: relaxed SMRF fitted to labelled samples, with a prior toward the defaults.

`fit` minimises, per parameter group g (one set of thresholds shared by the samples mapped
to it),

    sum_c w_c * L(c; theta_g(c)) + prior * sum_g ||(theta_g - theta_default) / (hi - lo)||^2,

where L is the expected total error (or 1 - soft kappa) of sample c, pooled over its tiles,
under the relaxed pipeline (`gfjax.smrf.tuning`) at a temperature annealed geometrically
(default 0.1 m -> 0.01 m, Adam step 0.15: on 5 ISPRS samples, 40 steps, these reached a lower
hard error than 0.3 m -> 0.02 m or a step of 0.08; SPEC section 7 suggests 1 m -> 0.05 m). Adam acts on the unconstrained `raw` parameters (`gfjax.tune.params`).
Every `eval_every` steps the hard (plain-filter) total error is measured and the best
iterate per group is kept, so the result is never worse on the training labels than the
starting point. The static window is searched on `GRID["window_m"]`: a fit per value.

The out-of-sample guard (cross-validation and a paired test against the
defaults) is `gfjax.tune.guard.validate`.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from gfjax import metrics
from gfjax.tune import params as tparams
from gfjax.tune import relax
from gfjax.tune.problem import Problem
from gfjax.tune.tuners import GradientTuner

__all__ = ["Settings", "FitResult", "fit", "hard_ground", "hard_errors", "hard_errors_at", "soft_loss",
           "LOSSES"]

LOSSES = ("total-error", "kappa")


@dataclasses.dataclass(frozen=True)
class Settings:
    """Tuning settings.

    Attributes:
      steps: Adam steps per window value.
      learning_rate: Adam step on the unconstrained parameters.
      temperature_start_m, temperature_end_m: geometric annealing of the relaxation [m].
      prior: weight of the squared distance to the defaults (bounded scale).
      loss: "total-error" (expected total error) or "kappa" (1 - soft kappa).
      windows_m: the grid of the method's static parameter (SMRF: window [m]); None: the
        method's default grid (`GradientTuner.grid`); ignored by methods without one (PMF).
      eval_every: steps between hard evaluations (best iterate kept).
    """

    steps: int = 60
    learning_rate: float = 0.15
    temperature_start_m: float = 0.1
    temperature_end_m: float = 0.01
    prior: float = 0.01
    loss: str = "total-error"
    windows_m: tuple[float, ...] | None = None
    eval_every: int = 10

    def __post_init__(self):
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if not (self.prior >= 0 and np.isfinite(self.prior)):
            raise ValueError(f"prior must be finite and >= 0, got {self.prior}")
        if self.windows_m is not None and (not self.windows_m or any(not w > 0 for w in self.windows_m)):
            raise ValueError(f"windows_m must hold values > 0, got {self.windows_m}")
        if self.eval_every < 1:
            raise ValueError(f"eval_every must be >= 1, got {self.eval_every}")


def _bucket_confusions(values, radius_px, bucket_prep, ref, cloud, mask, group, *, method, config, temperature,
                       n_samples):
    """Per-sample (soft or hard) confusion counts `(n_samples, 4)` of one bucket."""
    tile_values = values[group[cloud]]                                   # (b, p)

    def one(prep, vals):
        return method.ground_weight(prep, vals, config=config, static_px=radius_px, temperature=temperature)

    weight = jax.vmap(one)(bucket_prep, tile_values)                     # (b, cap)
    weight = weight.astype(jnp.float32)
    conf = jax.vmap(metrics.soft_confusion)(weight, ref, mask)            # 4 x (b,)
    stacked = jnp.stack(conf, axis=-1)                                    # (b, 4)
    return jax.ops.segment_sum(stacked, cloud, num_segments=n_samples)


def _confusions(values, radius_px, buckets, masks, group, *, method, config, temperature, n_samples):
    total = jnp.zeros((n_samples, 4), jnp.float32)
    for (prep, ref, cloud), mask in zip(buckets, masks):
        total = total + _bucket_confusions(values, radius_px, prep, ref, cloud, mask, group, method=method,
                                           config=config, temperature=temperature, n_samples=n_samples)
    return total


def _sample_loss(conf, kind: str):
    c = metrics.SoftConfusion(conf[..., 0], conf[..., 1], conf[..., 2], conf[..., 3])
    if kind == "kappa":
        return 1 - jax.vmap(metrics.soft_kappa)(c)
    return jax.vmap(metrics.expected_total_error)(c)


@functools.partial(jax.jit, static_argnames=("config", "kind", "n_samples", "method"))
def soft_loss(raw, radius_px, temperature, buckets, masks, group, weight, prior, *, config, kind: str,
              n_samples: int, method: GradientTuner, center=None):
    """Relaxed objective (scalar) for unconstrained `raw` `(g, 3)` (ordered as `method.bounds`)
    with the static parameter at `radius_px` (SMRF: openings, traced int32); `group` int32
    `(c,)` maps samples to rows of `raw`, `weight` float32 `(c,)` weighs their losses; the prior
    pulls toward `center` `(p,)` (None: the method's defaults; `Problem.defaults`)."""
    values = tparams.from_raw(raw, method.bounds)
    conf = _confusions(values, radius_px, buckets, masks, group, method=method, config=config,
                       temperature=temperature, n_samples=n_samples)
    data = jnp.sum(weight * _sample_loss(conf, kind))
    return data + prior * jnp.sum(tparams.prior_penalty(raw, method.bounds, center))


_soft_value_and_grad = jax.jit(jax.value_and_grad(soft_loss.__wrapped__),
                               static_argnames=("config", "kind", "n_samples", "method"))


@functools.partial(jax.jit, static_argnames=("config", "method"))
def _hard_ground(values, radius_px, buckets, group, *, config, method: GradientTuner):
    """Plain-filter labels per bucket, bool `(b, cap)`, for values `(g, 3)`."""
    out = []
    for prep, _, cloud in buckets:
        tile_values = values[group[cloud]]

        def one(p, v):
            return method.ground_weight(p, v, config=config, static_px=radius_px, temperature=None)

        out.append(jax.vmap(one)(prep, tile_values))
    return tuple(out)


def _arrays(problem: Problem):
    return tuple((b.prep, b.ref, b.cloud) for b in problem.buckets)


def hard_ground(problem: Problem, values: np.ndarray, group: np.ndarray, window_m: float) -> list[np.ndarray]:
    """Plain-filter ground labels per bucket, bool `(b, cap)` (numpy), for values `(g, 3)`
    (ordered as `problem.method.bounds`) with one static value (SMRF: window [m]) for all
    groups; `problem.labels` maps them to points."""
    method = problem.method
    radius = jnp.asarray(method.static_px(problem.config, window_m), jnp.int32)
    out = _hard_ground(jnp.asarray(values, jnp.float32), radius, _arrays(problem), jnp.asarray(group, jnp.int32),
                       config=problem.config, method=method)
    return [np.asarray(g) for g in out]


def _confusion_counts(problem: Problem, ground: list[np.ndarray], masks) -> np.ndarray:
    """Per sample int64 `(c, 4)` counts (tp, fp, fn, tn) of per-bucket labels on `masks`."""
    conf = np.zeros((problem.n_samples, 4), np.int64)
    for bucket, pred, mask in zip(problem.buckets, ground, masks):
        ref, mask, cloud = np.asarray(bucket.ref), np.asarray(mask), np.asarray(bucket.cloud)
        cells = np.stack([pred & ref, pred & ~ref, ~pred & ref, ~pred & ~ref], axis=-1) & mask[..., None]
        np.add.at(conf, cloud, cells.sum(axis=1))
    return conf


def hard_errors(problem: Problem, values: np.ndarray, masks, group: np.ndarray, window_m: float,
                *, kind: str = "total-error") -> np.ndarray:
    """Plain-filter error per sample, float64 `(c,)`: total error (or 1 - kappa) of the hard
    labels on the masked points, for values `(g, 3)` (ordered as `problem.method.bounds`)."""
    conf = _confusion_counts(problem, hard_ground(problem, values, group, window_m), masks)
    key = "total_error" if kind == "total-error" else "kappa"
    out = np.array([metrics.metrics_from_confusion(*map(int, c))[key] for c in conf])
    return out if kind == "total-error" else 1 - out


class FitResult(NamedTuple):
    """Outcome of `fit`, per group g.

    Attributes:
      values: float32 `(g, 3)` thresholds ordered as `problem.method.bounds` (the best hard
        iterate).
      window_m: float64 `(g,)` chosen static value (SMRF: window [m]; PMF: the config's max
        window, not searched).
      train_error: float64 `(g,)` hard training objective of the result: the weighted error
        over its samples plus `prior` times the distance to the defaults.
      start_error: float64 `(g,)` the same for the starting values.
      history: per window, dict of arrays: `loss` `(steps,)`, `values` `(steps, g, 3)`,
        `temperature` `(steps,)`.
      hard_evaluations: plain-filter evaluations of all samples (one forward pass each).
      gradient_calls: relaxed value-and-grad calls (each costs about 2-3 forward passes; the
        experiments measure the ratio).
      seconds: wall time.
    """

    values: np.ndarray
    window_m: np.ndarray
    train_error: np.ndarray
    start_error: np.ndarray
    history: dict
    hard_evaluations: int
    gradient_calls: int
    seconds: float


def _group_error(per_sample: np.ndarray, group: np.ndarray, weight: np.ndarray, n_groups: int) -> np.ndarray:
    out = np.zeros(n_groups)
    np.add.at(out, group, weight * per_sample)
    return out


def _penalty(values: np.ndarray, method: GradientTuner, center: np.ndarray | None = None) -> np.ndarray:
    """`params.prior_penalty` on bounded values `(g, 3)` (numpy), `(g,)`; `center` `(p,)` as
    there (None: the method's defaults)."""
    span = np.asarray([b.hi - b.lo for b in method.bounds])
    center = method.defaults if center is None else np.asarray(center)
    return np.sum(np.square((np.asarray(values, np.float64) - center) / span), axis=-1)


def fit(problem: Problem, settings: Settings = Settings(), *, masks=None, group=None, weight=None,
        start: np.ndarray | None = None, progress: bool = False) -> FitResult:
    """Fit a method's three thresholds (gradient) and static parameter (grid) to labels:
    SMRF's slope, threshold and scalar and its window; PMF's slope, initial and max distance.

    Args:
      problem: the prepared samples.
      settings: steps, temperatures, prior, loss, window grid.
      masks: `problem.masks(...)`: which labelled points count (default: all).
      group: int `(c,)` parameter group of each sample (default: one shared group).
      weight: float `(c,)` weight of each sample's loss (default: 1 / samples per group);
        a sample of weight 0 does not influence the fit.
      start: float `(g, 3)` starting values (default: `problem.defaults`, also the prior's
        centre).
      progress: tqdm bar over steps.

    Returns:
      A `FitResult`; per group the window and thresholds with the lowest hard training
      objective (error + prior penalty) among the evaluated iterates (the start included).
    """
    t0 = time.perf_counter()
    c = problem.n_samples
    masks = problem.masks() if masks is None else masks
    group = np.zeros(c, np.int32) if group is None else np.asarray(group, np.int32)
    n_groups = int(group.max()) + 1
    if weight is None:
        counts = np.bincount(group, minlength=n_groups)
        weight = 1.0 / counts[group]
    weight = np.asarray(weight, np.float64)
    method = problem.method
    bounds = method.bounds
    center = np.asarray(problem.defaults, np.float32)
    start = np.tile(center, (n_groups, 1)) if start is None else np.asarray(start, np.float32)
    arrays = _arrays(problem)
    group_j, weight_j = jnp.asarray(group), jnp.asarray(weight, jnp.float32)
    temps = relax.geometric_schedule(settings.temperature_start_m, settings.temperature_end_m, settings.steps)
    optimiser = optax.adam(settings.learning_rate)
    prior = jnp.asarray(settings.prior, jnp.float32)
    passes = grads = 0

    def evaluate(values, window_m):
        nonlocal passes
        passes += 1
        errs = hard_errors(problem, values, masks, group, window_m, kind=settings.loss)
        return _group_error(errs, group, weight, n_groups) + settings.prior * _penalty(values, method, center)

    grid = method.grid_values(problem.config, settings.windows_m)
    default_window = method.default_static(problem.config)
    start_window = default_window if default_window in grid else grid[0]
    best_values = start.copy()
    best_window = np.full(n_groups, start_window)
    start_error = evaluate(start, start_window)
    best_error = start_error.copy()
    history = {}
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=settings.steps * len(grid), desc=f"tune {method.name}", unit="step")
    for window_m in grid:
        radius = jnp.asarray(method.static_px(problem.config, window_m), jnp.int32)
        if window_m != start_window:
            errs = evaluate(start, window_m)
            better = errs < best_error
            best_error = np.where(better, errs, best_error)
            best_window = np.where(better, window_m, best_window)
            best_values[better] = start[better]
        raw = jnp.stack([tparams.to_raw(dict(zip([b.name for b in bounds], row)), bounds) for row in start])
        with jax.numpy_dtype_promotion("standard"):
            state = optimiser.init(raw)
        losses, trail = [], []
        for step in range(settings.steps):
            loss, g = _soft_value_and_grad(raw, radius, temps[step], arrays, masks, group_j, weight_j,
                                           prior, config=problem.config, kind=settings.loss, n_samples=c,
                                           method=method, center=jnp.asarray(center))
            grads += 1
            with jax.numpy_dtype_promotion("standard"):   # optax: float ** int32 step count
                updates, state = optimiser.update(g, state, raw)
                raw = optax.apply_updates(raw, updates)
            values = np.asarray(tparams.from_raw(raw, bounds))
            losses.append(float(loss))
            trail.append(values)
            if (step + 1) % settings.eval_every == 0 or step == settings.steps - 1:
                errs = evaluate(values, window_m)
                better = errs < best_error
                best_error = np.where(better, errs, best_error)
                best_window = np.where(better, window_m, best_window)
                best_values[better] = values[better]
            if bar is not None:
                bar.update(1)
                bar.set_postfix({method.static or "static": window_m, "loss": f"{float(loss):.4f}"})
        history[float(window_m)] = {"loss": np.asarray(losses), "values": np.stack(trail),
                                    "temperature": np.asarray(temps)}
    if bar is not None:
        bar.close()
    return FitResult(best_values, best_window, best_error, start_error, history, passes, grads,
                     time.perf_counter() - t0)


def hard_errors_at(problem: Problem, values: np.ndarray, window_m: np.ndarray, masks, group: np.ndarray,
                   *, kind: str = "total-error") -> np.ndarray:
    """`hard_errors` where each group has its own window (`window_m` float `(g,)`)."""
    window_m = np.asarray(window_m, np.float64)
    out = np.zeros(problem.n_samples)
    for w in np.unique(window_m):
        errs = hard_errors(problem, values, masks, group, float(w), kind=kind)
        use = window_m[group] == w
        out[use] = errs[use]
    return out
