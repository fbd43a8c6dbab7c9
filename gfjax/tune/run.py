"""`gfjax.tune.tune`: a method's settings fitted to labelled clouds and guarded, in one call.

```python
import gfjax
tuned = gfjax.tune.tune([gfjax.read("labelled.laz")], "smrf")
result = gfjax.smrf.filter(cloud, config=tuned.config, params=tuned.params)
tuned.write("params.json")                 # what `gfjax filter --params` reads
```

What `gfjax tune` runs (its help says it in full): a method with a gradient (`Method.tuning ==
"gradient"`: SMRF, PMF, CSF) is fitted by Adam on its relaxed form from the values `gfjax
filter` would choose on these clouds (`gfjax.adaptive`), its static setting on a grid; a method
without one ("grid": MASF, DMF) tries every combination of a grid. Either way the guard
(`gfjax.tune.guard`, `gfjax.tune.search`) keeps the fit only where cross-validation by cloud (or
by spatial block of a single cloud) says it beats the defaults; otherwise the defaults come back.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gfjax.errors import InputError

__all__ = ["Tuned", "tune"]


@dataclasses.dataclass(frozen=True)
class Tuned:
    """What `tune` found.

    Attributes:
      method: the method's name.
      config, params: the method's `Config` and `Params` to filter with: `values` over the
        settings the fit started from (those `gfjax filter` chooses on the training clouds).
      values: `{key: value}` the settings to filter with (the fit where the guard kept it, else
        the defaults), as params.json holds them.
      units: each value's unit.
      validation: the guard's figures: out-of-fold total error of the defaults ("default") and
        of the fit ("tuned"), p-value, "kept", the folds' errors.
      fitted: the keys whose value differs from the defaults.
      record: everything else params.json records (the grid, the start values and the
        terrain they came from, the training files).
    """

    method: str
    config: Any
    params: Any
    values: dict[str, float]
    units: dict[str, str]
    validation: dict[str, Any]
    fitted: list[str]
    record: dict[str, Any]

    def write(self, path: str | Path) -> Path:
        """Write params.json (`gfjax filter --params`), atomically. Returns the path."""
        from gfjax.tune.params import write_params

        return write_params(path, method=self.method, values=self.values, units=self.units,
                            extra={"fitted": self.fitted, "validation": self.validation, **self.record})


def tune(clouds: Sequence, method: str = "smrf", *, folds: int = 3, block_m: float = 50.0, alpha: float = 0.05,
         grid: Mapping[str, Sequence[float]] | None = None, loss: str = "total-error", prior: float = 0.01,
         steps: int = 60, returns: str = "all", names: Sequence[str] | None = None,
         progress: bool = False) -> Tuned:
    """Fit `method`'s settings to labelled clouds (ground = class 2), guarded by cross-validation.

    Args:
      clouds: `gfjax.Cloud`s with reference classes (read in metres as `gfjax.read` gives them).
      method: a method whose `Method.tuning` is "gradient" or "grid".
      folds: the guard's folds, by cloud when several are given, else by square blocks of
        `block_m` metres; 0 or 1: no guard (the fit is kept where it lowered the training error).
      alpha: level of the guard's one-sided test.
      grid: the values searched for a key: SMRF `window_m`; CSF `time_step` and `rigidness`;
        any key of MASF's and DMF's grids (`gfjax.masf.tuning.default_grid`, `...dmf...`).
        Keys not given keep their default values.
      loss: "total-error" or "kappa" (1 - soft kappa); a grid method uses total error only.
      prior: weight of the pull toward the start values (gradient methods).
      steps: Adam steps per grid value (gradient methods).
      returns: "all" or "last": the returns the filter uses.
      names: the clouds' names for the record (default: each cloud's name).
      progress: show progress bars.

    Returns:
      `Tuned`.

    Raises:
      InputError: a method that cannot be tuned, a grid key or value it does not have, a loss
        it does not use, or clouds without reference ground.
    """
    from gfjax import methods

    found = methods.get(method, option="method")
    if found.tuning is None:
        tunable = [name for name in methods.available() if methods.get(name).tuning is not None]
        raise InputError(f"method: {method!r} has no thresholds to tune; tunable: {', '.join(tunable)}")
    grid = checked_grid(method, grid or {})
    names = [str(n) for n in (names or [c.name for c in clouds])]
    samples, terrain = labelled_samples(clouds, returns=returns)
    if found.tuning == "grid":
        return _searched(found, samples, grid, loss=loss, folds=folds, block_m=block_m, alpha=alpha,
                         names=names, progress=progress)
    return _fitted(found, samples, terrain, grid, loss=loss, prior=prior, steps=steps, folds=folds,
                   block_m=block_m, alpha=alpha, names=names, progress=progress)


def checked_grid(method: str, grid: Mapping[str, Sequence[float]], *, option: str = "grid") -> dict[str, tuple]:
    """`grid` checked against what `method` searches: SMRF `window_m`, CSF `time_step` and
    `rigidness`, MASF's and DMF's grid keys (`gfjax.<method>.tuning.default_grid`); each value in
    the key's range (`gfjax.limits`), a whole number of an integer key as an int.

    Raises:
      InputError: an unknown key or a value out of range, naming `option`.
    """
    from gfjax import limits, methods
    from gfjax.tune import tuners

    found = methods.get(method, option="method")
    tuner = tuners.get(method)
    if found.tuning == "grid":
        keys, ranges = set(tuner.default_grid(found.Config())), {**found.ranges, **tuner.grid_ranges}
    else:
        keys, ranges = set(tuner.grid_keys), found.ranges
    out = {}
    for key, values in grid.items():
        if key not in keys:
            raise InputError(f"{option} {key}: unknown key; {method} searches {', '.join(sorted(keys)) or 'none'}")
        allowed = ranges[key]
        if allowed.integer:             # a whole number given as "2" or "2.0" is the integer 2
            values = tuple(int(v) if float(v).is_integer() else v for v in values)
        for value in values:
            try:
                limits.check_value(key, value, allowed)
            except ValueError as err:
                raise InputError(f"{option}: {err}") from None
        out[key] = tuple(values)
    return out


def labelled_samples(clouds: Sequence, *, returns: str = "all") -> tuple[list, Any]:
    """The clouds as `gfjax.tune.problem.Sample`s and their terrain together
    (`gfjax.adaptive.combine`); InputError when none holds class 2."""
    from gfjax import adaptive
    from gfjax.tune.problem import Sample

    samples, terrains = [], []
    for cloud in clouds:
        samples.append(Sample.from_cloud(cloud, returns=returns))
        use = cloud.filter_mask(returns)
        if use.any():
            xyz = cloud.xyz_m
            terrains.append(adaptive.measure(xyz[use], xyz[cloud.filter_mask("last")]))
    if not any(np.any(s.ref_ground[s.use]) for s in samples):
        raise InputError(f"{', '.join(c.name for c in clouds)}: no reference ground (class 2) to tune on")
    return samples, adaptive.combine(terrains)


def _validation(folds: int, by_sample: bool, block_m: float, measure: str, alpha: float, **figures) -> dict:
    return {"folds": folds, "measure": measure,
            "units": ("files" if by_sample else f"blocks of {block_m:g} m") if folds >= 2 else None,
            **figures, "alpha": alpha}


def _fitted(found, samples, terrain, grid, *, loss, prior, steps, folds, block_m, alpha, names, progress) -> Tuned:
    """A method with a gradient: Adam on its relaxed form, its static setting on a grid, guarded."""
    from gfjax import adaptive
    from gfjax.tune import fit as tfit
    from gfjax.tune import guard, tuners
    from gfjax.tune.problem import Problem

    method = tuners.get(found.name)
    settled = adaptive.settle_terrain(found.adapt, terrain, method.config_type(), found.Params())
    config = settled.config
    start = [float(settled.chosen.get(b.name, b.default)) for b in method.bounds]   # exact, as params.json holds them
    windows = method.grid_values(config, method.static_grid(grid))
    settings = tfit.Settings(steps=steps, prior=prior, loss=loss, windows_m=windows)
    problem = Problem(samples, config=config, max_window_m=max(windows), method=method, grid=windows, defaults=start)
    v = guard.validate(problem, settings, folds=folds, block_m=block_m, alpha=alpha, progress=progress)
    names_ = [b.name for b in method.bounds]
    kept = bool(v.kept[0])
    values = {b.name: float(x) if kept else d for b, x, d in zip(method.bounds, v.values[0], start, strict=True)}
    static_values = method.params_values(float(v.window_m[0])) if method.static else {}
    values |= static_values
    span = {b.name: b.hi - b.lo for b in method.bounds}
    defaults = dict(zip(names_, start, strict=True))
    fitted = [k for k in names_ if kept and abs(values[k] - defaults[k]) > 1e-4 * span[k]]
    kind = "1 - kappa" if loss == "kappa" else "total error"
    validation = _validation(folds, bool(v.by_sample[0]), block_m, "total error" if folds >= 2 else kind, alpha,
                             default=float(v.default_error[0]), tuned=float(v.tuned_error[0]),
                             shrink=float(v.shrink[0]), p_value=float(v.p_value[0]),
                             changed_units=int(v.units[0]), kept=kept, per_fold=v.fold_errors[:, 0, :].tolist())
    record = {"loss": loss, "prior": prior, "steps": steps, "training_files": list(names),
              "start": {"values": defaults, "chosen_from_terrain": settled.chosen,
                        "terrain": settled.terrain._asdict() if settled.terrain is not None else None}}
    if method.static == "window_m":
        record |= {"grid": {method.static: list(windows)},
                   "window_chosen_from_grid": kept and values[method.static] != method.default_static(config),
                   "not_differentiable": {method.static: method.static_note}}
    elif method.static:
        static_defaults = method.params_values(method.default_static(config))
        grid_values = [method.params_values(w) for w in windows]
        record |= {"grid": {k: sorted({g[k] for g in grid_values}) for k in static_values},
                   "grid_chosen": {k: kept and static_values[k] != static_defaults[k] for k in static_values},
                   "not_differentiable": {k: method.static_note for k in static_values}}
    config, params = _with_values(found, values, config)
    return Tuned(found.name, config, params, values, dict(method.units), validation, fitted, record)


def _searched(found, samples, grid, *, loss, folds, block_m, alpha, names, progress) -> Tuned:
    """A method without a gradient: every combination of its grid, the guard's choice."""
    from gfjax.tune import search, tuners

    if loss != "total-error":
        raise InputError(f"loss {loss}: {found.name} is searched on total error only")
    tuner = tuners.get(found.name)
    config = found.Config()
    searched = tuner.default_grid(config) | grid
    try:
        result = tuner.tune(samples, config=config, grid=searched, folds=folds, block_m=block_m, alpha=alpha,
                            progress=progress)
    except ValueError as err:
        raise InputError(f"grid: {err}") from None
    v = result.choice
    defaults, chosen = result.combos[result.default], result.combos[v.index]
    fitted = [k for k in chosen if chosen[k] != defaults[k]]
    validation = _validation(folds, bool(v.by_sample), block_m, "total error", alpha,
                             default=v.default_error, tuned=v.tuned_error, p_value=v.p_value,
                             changed_units=v.units, kept=v.kept, per_fold=v.fold_errors.tolist(),
                             best_on_all_labels=tuner.values(result.combos[v.best]))
    record = {"search": "exhaustive grid",
              "choice": "one-standard-error rule: the candidate nearest the defaults within one standard error "
                        f"plus {search.TIE_MARGIN:g} of the best" if folds >= 2 else "lowest training error",
              "grid": {k: sorted({c[k] for c in result.combos}) for k in defaults},
              "not_differentiable": {k: tuner.note for k in defaults},
              "training_files": list(names)}
    config, params = _with_values(found, result.values, config)
    return Tuned(found.name, config, params, dict(result.values), dict(tuner.units), validation, fitted, record)


def _with_values(found, values: Mapping[str, float], config) -> tuple[Any, Any]:
    """The method's `Config` and `Params`: `values` over `config`."""
    from gfjax import methods

    return methods.make_config_and_params(found, values=values, values_source="tuned values", base_config=config)
