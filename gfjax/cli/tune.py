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
0.5,0.75,1, height_threshold_m 0,0.25,0.5, height_threshold_w 0,0.1,0.15,0.2,0.25,0.4, 810 final
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
    from gfjax.tune import tune

    tuning = methods.get(args.method).tuning
    if tuning is None:
        tunable = [name for name in methods.available() if methods.get(name).tuning is not None]
        raise InputError(f"--method: {args.method!r} has no thresholds to tune; tunable: {', '.join(tunable)}")
    out = Path(args.output)
    inputs = las_io.expand_inputs(args.inputs)
    _job.check_outputs([("-o", out, (".json",))], inputs=inputs, force=args.force)
    check_inputs(inputs, units=args.units)
    grid = _grid(args, tuning)
    clouds = [las_io.read(path, units=args.units) for path in inputs]
    tuned = tune(clouds, args.method, folds=args.folds, block_m=args.block, alpha=args.alpha, grid=grid,
                 loss=args.loss, prior=args.prior, steps=args.steps, returns=args.returns, names=[str(p) for p in inputs],
                 progress=True)
    tuned.write(out)
    _summary(out, tuned, kind="1 - kappa" if args.loss == "kappa" else "total error")
    return 0


def _grid(args: argparse.Namespace, tuning: str) -> dict[str, tuple]:
    """The grid `gfjax.tune.tune` searches, from `--windows`, `--time-steps`, `--rigidness` and
    `--grid`, each checked against the method's tuner (InputError naming the option)."""
    from gfjax import methods
    from gfjax.tune import tuners

    tuner = tuners.get(args.method)
    given = {"--windows": ("window_m", args.windows), "--time-steps": ("time_step", args.time_steps),
             "--rigidness": ("rigidness", args.rigidness)}
    if tuning == "grid":
        if args.loss != "total-error":
            raise InputError(f"--loss {args.loss}: {args.method} is searched on total error only")
    elif args.grid:
        searched = [name for name in methods.available() if methods.get(name).tuning == "grid"]
        raise InputError(f"--grid: only {', '.join(searched)} are tuned on a grid of settings, not {args.method}")
    for option, (key, value) in given.items():
        if value and key not in getattr(tuner, "grid_keys", ()):
            raise InputError(f"{option}: not a setting of {args.method}'s tuning grid")
    if tuning == "grid":
        from gfjax.tune.run import checked_grid

        return checked_grid(args.method, dict(args.grid), option="--grid")
    _check_grids(args)
    return {key: value for key, value in given.values() if value}


def _summary(out, tuned, *, kind: str = "total error") -> None:
    """The lines `gfjax tune` prints: the values written, then what the guard decided."""
    values, validation, fitted = tuned.values, tuned.validation, tuned.fitted
    print(f"{out}: {tuned.method} " + ", ".join(f"{k}={values[k]:.4g}" for k in values))
    if validation["units"] is not None:
        shrink = validation.get("shrink")
        level = f" (shrink {shrink:.2f})" if shrink is not None else ""
        print(f"validation ({validation['folds']} folds by {validation['units']}): out-of-fold total error defaults "
              f"{validation['default']:.4f}, tuned {validation['tuned']:.4f}{level}, "
              f"p = {validation['p_value']:.3g} over {validation['changed_units']} units -> "
              f"{'fitted values kept' if validation['kept'] else 'defaults kept (no significant gain)'}; "
              f"fitted: {', '.join(fitted) or 'none'}")
    else:
        print(f"no validation: training {kind} defaults {validation['default']:.4f}, tuned "
              f"{validation['tuned']:.4f}; fitted: {', '.join(fitted) or 'none'}")
