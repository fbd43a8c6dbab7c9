"""`gfjax tune TRAIN... --method smrf|pmf|csf|masf -o params.json`: fit a filter's thresholds to labelled files.

The thresholds (SMRF: slope, threshold_m, scalar; PMF: slope, initial_distance_m,
max_distance_m; CSF: class_threshold_m) are fitted by Adam on a relaxed (sigmoid) form of the
filter against the files' reference labels (ground = class 2), SMRF's window on a small grid.
CSF's time step and rigidness act through the cloth simulation (a while loop: no gradient), so
they are chosen from a grid (`--time-steps` x `--rigidness`, default 0.5,0.65,0.8 x 1,2,3):
each cloth is simulated once per file, then the threshold is fitted on each; params.json lists
them as grid-searched, never as fitted by gradient. Several files are tuned together (one
parameter set, unweighted mean of their losses), batched under `jax.vmap` by tile shape. The
fit starts from the values `gfjax filter` would choose on these files (`gfjax.adaptive`: SMRF's
and PMF's cell, PMF's distances; the "defaults" below) and is regularised toward them
(`--prior`); params.json records them and the terrain they came from under "start".

MASF and DMF (`--method masf|dmf`) have no gradient to follow: MASF's alpha_max_m,
alpha_step_m, alpha_top_m, st and ft_m act through the alpha pyramid and a TIN grown on the host; DMF's v0
sets the voxel size W (whole metres), and max_filter_px, rc_min_share and the height rule's
height_threshold_m + height_threshold_w * W act in host code or bounded loops. Every
combination of a grid is tried (`--grid KEY=V,V,...` replaces one key's values; defaults:
MASF alpha_max_m 10,15,20,25, alpha_step_m 1,2,4,9, alpha_top_m 0 (none),90,
st 0.01,0.03,0.05,0.1,0.15, ft_m 0.3,0.5,0.7, 480 runs per file; DMF v0 1,1.5,2,2.5,3, max_filter_px 1,2,3, rc_min_share
0.5,0.75,1, height_threshold_m 0,0.25,0.5, height_threshold_w 0,0.1,0.15,0.25,0.4, 675 final
rules on 45 preparations per file). The candidate chosen is the nearest the defaults (in grid
steps) among those within one standard error of the lowest total error plus a margin of ties
(the one-standard-error rule; the standard error over the validation units below; the margin,
0.4 percentage points, is `gfjax.tune.search.TIE_MARGIN`), and it is guarded as below with a
single level.

Guard (tuned values are often worse than the defaults on other data): the labelled data are
cross-validated in `--folds` folds, by file when several files are given, else by square
spatial blocks of `--block` metres. Each fold is fitted on the other folds; on its held-out
points the plain filter is scored with the defaults and with points 1/3, 2/3 and all the
way along the segment defaults -> fit. The level with the lowest out-of-fold total error is
tested against the defaults with a one-sided sign-flip test over the units (files or blocks)
of their paired error differences, Bonferroni-corrected for the 3 levels. Only when it is
significant at `--alpha` (default 0.05) does params.json hold that level of the fit on all
data; otherwise it holds the defaults and says so. Fewer than 6 units that change can never
pass (3 x 2^-5 > 0.05). The figures (out-of-fold errors, p-value, level) are printed and stored in params.json.
Use the result with `gfjax filter --params params.json`.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from gfjax.cli import _job
from gfjax.cli._common import add_units_option, check_inputs, positive_float, positive_int, ranged
from gfjax.errors import InputError


def _positive_list(item: Callable[[str], float | int]) -> Callable[[str], tuple]:
    """argparse type: a non-empty comma-separated list, each value checked by `item`
    (`positive_float` for windows and time steps, `positive_int` for rigidness)."""
    def parse(text: str) -> tuple:
        values = tuple(item(v) for v in text.split(",") if v.strip())
        if not values:
            raise argparse.ArgumentTypeError(f"expected comma-separated values, got {text!r}")
        return values
    return parse


def _level(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1), got {text!r}")
    return value


def _grid_item(text: str) -> tuple[str, tuple[float, ...]]:
    """argparse type of `--grid`: `KEY=V,V,...` with at least one number."""
    key, sep, values = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=V,V,..., got {text!r}")
    parsed = []
    for v in values.split(","):
        try:
            parsed.append(float(v))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{key}: expected numbers, got {v!r}") from None
    return key.strip(), tuple(parsed)


def _check_grids(args: argparse.Namespace) -> None:
    """Each value of `--windows`, `--time-steps`, `--rigidness` in the range of the key it
    sets (the method's RANGES, `gfjax.limits`)."""
    from gfjax import limits, methods

    ranges = methods.get(args.method).ranges
    for option, key, values in (("--windows", "window_m", args.windows), ("--time-steps", "time_step", args.time_steps),
                                ("--rigidness", "rigidness", args.rigidness)):
        allowed = ranges.get(key)
        for value in (values or ()) if allowed is not None else ():
            try:
                limits.check_value(key, value, allowed)
            except ValueError as err:
                raise InputError(f"{option}: {err}") from None


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("tune", help="fit a method's thresholds against labelled files",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="TRAIN", help="labelled LAS/LAZ files (ground = class 2)")
    parser.add_argument("-o", "--output", required=True, metavar="PARAMS.json", help="params file to write")
    parser.add_argument("--method", default="smrf", metavar="NAME",
                        help="method to tune (default smrf): its thresholds by gradient, or a grid of its "
                             "settings")
    parser.add_argument("--loss", choices=("total-error", "kappa"), default="total-error",
                        help="expected total error (default) or 1 - soft kappa")
    parser.add_argument("--prior", type=ranged("--prior"), default=0.01, metavar="W",
                        help="weight of the pull toward the defaults (default 0.01)")
    parser.add_argument("--steps", type=ranged("--steps"), default=60, help="Adam steps per window (default 60)")
    parser.add_argument("--folds", type=ranged("--folds"), default=3,
                        help="folds of the guard's cross-validation, by file or by block (default 3; "
                             "0 or 1: no guard, the fit is kept where it lowered the training error)")
    parser.add_argument("--block", type=ranged("--block"), default=50.0, metavar="M",
                        help="side of the validation blocks of a single file [m] (default 50)")
    parser.add_argument("--alpha", type=_level, default=0.05,
                        help="level of the guard's test, in (0, 1) (default 0.05)")
    parser.add_argument("--windows", type=_positive_list(positive_float), default=None, metavar="M,M,...",
                        help="SMRF's window grid [m] (default 12,18,24; PMF keeps its window series)")
    parser.add_argument("--time-steps", type=_positive_list(positive_float), default=None, metavar="DT,DT,...",
                        help="CSF's time-step grid, each in (0, 10) (default 0.5,0.65,0.8)")
    parser.add_argument("--rigidness", type=_positive_list(positive_int), default=None, metavar="R,R,...",
                        help="CSF's rigidness grid (default 1,2,3)")
    parser.add_argument("--grid", action="append", type=_grid_item, default=[], metavar="KEY=V,V,...",
                        help="MASF, DMF: the values tried for one key of the grid (see above); repeatable")
    parser.add_argument("--returns", choices=("all", "last"), default="all", help="returns used (default all)")
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite an existing params file")
    return parser


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from gfjax import methods
    from gfjax.io import las as las_io

    tuning = methods.get(args.method).tuning
    if tuning is None:
        tunable = [name for name in methods.available() if methods.get(name).tuning is not None]
        raise InputError(f"--method: {args.method!r} has no thresholds to tune; tunable: {', '.join(tunable)}")
    out = Path(args.output)
    inputs = las_io.expand_inputs(args.inputs)
    _job.check_outputs([("-o", out, (".json",))], inputs=inputs, force=args.force)
    check_inputs(inputs, units=args.units)
    if args.grid and tuning != "grid":
        searched = [name for name in methods.available() if methods.get(name).tuning == "grid"]
        raise InputError(f"--grid: only {', '.join(searched)} are tuned on a grid of settings, not {args.method}")
    if tuning == "grid":
        return _run_search(args, inputs, out)


    from gfjax.tune import fit as tfit
    from gfjax.tune import guard
    from gfjax.tune import methods as tmethods
    from gfjax.tune.params import write_params
    from gfjax.tune.problem import Problem

    method = tmethods.get(args.method)
    if args.windows and method.static != "window_m":
        raise InputError(f"--windows: {args.method} has no window grid")
    for option, value in (("--time-steps", args.time_steps), ("--rigidness", args.rigidness)):
        if value and method.name != "csf":
            raise InputError(f"{option}: only CSF has a cloth grid, not {args.method}")
    _check_grids(args)
    samples, terrain = _labelled_samples(args, inputs)
    config, start, settled = _start(method, terrain)
    if method.name == "csf":
        from gfjax.tune import csf as tcsf

        windows = tuple(tcsf.encode(t, r) for r in args.rigidness or tcsf.RIGIDNESS
                        for t in args.time_steps or tcsf.TIME_STEPS)
    else:
        windows = method.grid_values(config, args.windows)
    settings = tfit.Settings(steps=args.steps, prior=args.prior, loss=args.loss, windows_m=windows)
    problem = Problem(samples, config=config, max_window_m=max(windows), method=method, grid=windows, defaults=start)
    v = guard.validate(problem, settings, folds=args.folds, block_m=args.block, alpha=args.alpha, progress=True)
    names = [b.name for b in method.bounds]
    kept = bool(v.kept[0])
    values = {b.name: float(x) if kept else d for b, x, d in zip(method.bounds, v.values[0], start)}
    static_values = method.params_values(float(v.window_m[0])) if method.static else {}
    values |= static_values
    span = {b.name: b.hi - b.lo for b in method.bounds}
    defaults = dict(zip(names, start))
    fitted = [k for k in names if kept and abs(values[k] - defaults[k]) > 1e-4 * span[k]]
    kind = "1 - kappa" if args.loss == "kappa" else "total error"
    validation = {"folds": args.folds, "measure": "total error" if args.folds >= 2 else kind,
                  "units": ("files" if v.by_sample[0] else f"blocks of {args.block:g} m") if args.folds >= 2 else None,
                  "default": float(v.default_error[0]), "tuned": float(v.tuned_error[0]),
                  "shrink": float(v.shrink[0]), "p_value": float(v.p_value[0]), "alpha": args.alpha,
                  "changed_units": int(v.units[0]), "kept": kept, "per_fold": v.fold_errors[:, 0, :].tolist()}
    extra = {"fitted": fitted, "validation": validation, "loss": args.loss, "prior": args.prior, "steps": args.steps,
             "training_files": [str(p) for p in inputs],
             "start": {"values": defaults, "chosen_from_terrain": settled.chosen,
                       "terrain": settled.terrain._asdict() if settled.terrain is not None else None}}
    if method.static == "window_m":
        extra |= {"grid": {method.static: list(windows)},
                  "window_chosen_from_grid": kept and values[method.static] != method.default_static(config),
                  "not_differentiable": {method.static: method.static_note}}
    elif method.static:
        static_defaults = method.params_values(method.default_static(config))
        grid = [method.params_values(w) for w in windows]
        extra |= {"grid": {k: sorted({g[k] for g in grid}) for k in static_values},
                  "grid_chosen": {k: kept and static_values[k] != static_defaults[k] for k in static_values},
                  "not_differentiable": {k: method.static_note for k in static_values}}
    write_params(out, method=args.method, values=values, units=method.units, extra=extra)
    _summary(out, args.method, values, validation, fitted, kind=kind, shrink=float(v.shrink[0]))
    return 0


def _run_search(args: argparse.Namespace, inputs, out) -> int:
    """A method tuned on a grid (`Method.tuning`): every combination of the grid, then the guard
    (`gfjax.tune.search`)."""
    import importlib

    from gfjax import limits, methods
    from gfjax.tune import search
    from gfjax.tune.params import write_params

    method = methods.get(args.method)
    tmodule = importlib.import_module(f"gfjax.tune.{args.method}")
    config = method.Config()

    for option, value in (("--windows", args.windows), ("--time-steps", args.time_steps),
                          ("--rigidness", args.rigidness)):
        if value:
            raise InputError(f"{option}: not a setting of {args.method}")
    if args.loss != "total-error":
        raise InputError(f"--loss {args.loss}: {args.method} is searched on total error only")
    grid = tmodule.default_grid(config)
    for key, values in args.grid:
        if key not in grid:
            raise InputError(f"--grid {key}: unknown key; {args.method} searches {', '.join(grid)}")
        allowed = tmodule.TUNER.grid_ranges.get(key, method.ranges[key])
        if allowed.integer:             # a whole number given as "2" or "2.0" is the integer 2
            values = tuple(int(v) if float(v).is_integer() else v for v in values)
        for value in values:
            try:
                limits.check_value(key, value, allowed)
            except ValueError as err:
                raise InputError(f"--grid: {err}") from None
        grid[key] = values
    samples, _ = _labelled_samples(args, inputs)      # no value of MASF's or DMF's follows the terrain
    try:
        tuned = tmodule.TUNER.tune(samples, config=config, grid=grid, folds=args.folds, block_m=args.block, alpha=args.alpha,
                           progress=True)
    except ValueError as err:
        raise InputError(f"--grid: {err}") from None
    v = tuned.choice
    defaults, chosen = tuned.combos[tuned.default], tuned.combos[v.index]
    fitted = [k for k in chosen if chosen[k] != defaults[k]]
    validation = {"folds": args.folds, "measure": "total error",
                  "units": ("files" if v.by_sample else f"blocks of {args.block:g} m") if args.folds >= 2 else None,
                  "default": v.default_error, "tuned": v.tuned_error, "p_value": v.p_value, "alpha": args.alpha,
                  "changed_units": v.units, "kept": v.kept, "per_fold": v.fold_errors.tolist(),
                  "best_on_all_labels": tmodule.TUNER.values(tuned.combos[v.best])}
    extra = {"fitted": fitted, "validation": validation, "search": "exhaustive grid",
             "choice": "one-standard-error rule: the candidate nearest the defaults within one standard error "
                       f"plus {search.TIE_MARGIN:g} of the best" if args.folds >= 2 else "lowest training error",
             "grid": {k: sorted({c[k] for c in tuned.combos}) for k in defaults},
             "not_differentiable": {k: tmodule.TUNER.note for k in defaults},
             "training_files": [str(p) for p in inputs]}
    write_params(out, method=args.method, values=tuned.values, units=tmodule.TUNER.units, extra=extra)
    _summary(out, args.method, tuned.values, validation, fitted)
    return 0


def _labelled_samples(args: argparse.Namespace, inputs) -> tuple[list, Any]:
    """The training files as `gfjax.tune.problem.Sample`s and their terrain together
    (`gfjax.adaptive.combine`); InputError when none holds class 2."""
    import numpy as np

    from gfjax import adaptive
    from gfjax.io import las as las_io
    from gfjax.tune.problem import Sample

    samples, terrains = [], []
    for path in inputs:
        cloud = las_io.read(path, units=args.units)
        samples.append(Sample.from_cloud(cloud, returns=args.returns))
        use = cloud.filter_mask(args.returns)
        if use.any():
            xyz = cloud.xyz_m
            terrains.append(adaptive.measure(xyz[use], xyz[cloud.filter_mask("last")]))
    if not any(np.any(s.ref_ground[s.use]) for s in samples):
        raise InputError(f"{', '.join(map(str, inputs))}: no reference ground (class 2) to tune on")
    return samples, adaptive.combine(terrains)


def _start(method, terrain) -> tuple:
    """The Config and the values vector `(p,)` a fit of `method` (`gfjax.tune.methods.GradientTuner`)
    starts from: the method's values that follow the data (`gfjax.adaptive`) on the training
    files' `terrain`, as `gfjax filter` would settle them on these files; and what was chosen."""
    from gfjax import adaptive, methods

    found = methods.get(method.name)
    settled = adaptive.settle_terrain(found.adapt, terrain, method.config_type(), found.Params())
    start = [float(settled.chosen.get(b.name, b.default)) for b in method.bounds]   # exact, as params.json holds them
    return settled.config, start, settled


def _summary(out, method: str, values: dict, validation: dict, fitted: list[str], *, kind: str = "total error",
             shrink: float | None = None) -> None:
    """The lines `gfjax tune` prints: the values written, then what the guard decided."""
    print(f"{out}: {method} " + ", ".join(f"{k}={values[k]:.4g}" for k in values))
    if validation["units"] is not None:
        level = f" (shrink {shrink:.2f})" if shrink is not None else ""
        print(f"validation ({validation['folds']} folds by {validation['units']}): out-of-fold total error defaults "
              f"{validation['default']:.4f}, tuned {validation['tuned']:.4f}{level}, "
              f"p = {validation['p_value']:.3g} over {validation['changed_units']} units -> "
              f"{'fitted values kept' if validation['kept'] else 'defaults kept (no significant gain)'}; "
              f"fitted: {', '.join(fitted) or 'none'}")
    else:
        print(f"no validation: training {kind} defaults {validation['default']:.4f}, tuned "
              f"{validation['tuned']:.4f}; fitted: {', '.join(fitted) or 'none'}")
