"""`gfjax tune TRAIN... --method smrf -o params.json`: fit a filter's thresholds to labelled files.

The thresholds (SMRF: slope, threshold_m, scalar) are fitted by Adam on a relaxed
(sigmoid) form of the filter against the files' reference labels (ground = class 2), the
window on a small grid (SPEC section 7). Several files are tuned together (one parameter set,
unweighted mean of their losses), batched under `jax.vmap` by tile shape. The fit is
regularised toward the defaults (`--prior`) and checked by k-fold validation on spatial
blocks of the labelled points (`--folds`, `--block`): the fitted values are written only when
they beat the defaults on the held-out blocks; otherwise params.json holds the defaults and
says so. Use the result with `gfjax filter --params params.json`.
"""
from __future__ import annotations

import argparse

from gfjax.cli._common import add_units_option, nonnegative_float, nonnegative_int, positive_float, positive_int
from gfjax.errors import InputError

TUNABLE = ("smrf",)


def _windows(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not values or any(not v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"windows must be > 0, got {text!r}")
    return values


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("tune", help="fit a method's thresholds against labelled files",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="TRAIN", help="labelled LAS/LAZ files (ground = class 2)")
    parser.add_argument("-o", "--output", required=True, metavar="PARAMS.json", help="params file to write")
    parser.add_argument("--method", default="smrf", help=f"method to tune ({', '.join(TUNABLE)})")
    parser.add_argument("--loss", choices=("total-error", "kappa"), default="total-error",
                        help="expected total error (default) or 1 - soft kappa")
    parser.add_argument("--prior", type=nonnegative_float, default=0.01, metavar="W",
                        help="weight of the pull toward the defaults (default 0.01)")
    parser.add_argument("--steps", type=positive_int, default=60, help="Adam steps per window (default 60)")
    parser.add_argument("--folds", type=nonnegative_int, default=3,
                        help="k-fold block validation (default 3; 0 or 1: no validation)")
    parser.add_argument("--block", type=positive_float, default=50.0, metavar="M",
                        help="side of the validation blocks [m] (default 50)")
    parser.add_argument("--windows", type=_windows, default=None, metavar="M,M,...",
                        help="window grid [m] (default 12,18,24)")
    parser.add_argument("--returns", choices=("all", "last"), default="all", help="returns used (default all)")
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite an existing params file")
    return parser


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from gfjax.io import las as las_io

    if args.method not in TUNABLE:
        raise InputError(f"--method: {args.method!r} cannot be tuned yet; tunable: {', '.join(TUNABLE)}")
    out = Path(args.output)
    if out.suffix.lower() != ".json":
        raise InputError(f"-o {out}: the params file must end in .json")
    if out.exists() and not args.force:
        raise InputError(f"-o {out}: exists (use --force to overwrite)")
    if not out.parent.is_dir():
        raise InputError(f"-o {out}: folder {out.parent} does not exist")
    inputs = las_io.expand_inputs(args.inputs)
    for path in inputs:
        las_io.read_header(path)

    import numpy as np

    from gfjax.smrf import Config
    from gfjax.tune import fit as tfit
    from gfjax.tune import smrf as tsmrf
    from gfjax.tune.params import write_params
    from gfjax.tune.problem import Problem, Sample

    samples = [Sample.from_cloud(las_io.read(p, units=args.units), returns=args.returns) for p in inputs]
    if not any(np.any(s.ref_ground[s.use]) for s in samples):
        raise InputError(f"{', '.join(map(str, inputs))}: no reference ground (class 2) to tune on")
    windows = args.windows or tsmrf.GRID["window_m"]
    settings = tfit.Settings(steps=args.steps, prior=args.prior, loss=args.loss, windows_m=windows)
    problem = Problem(samples, config=Config(), max_window_m=max(windows))
    v = tfit.validate(problem, settings, folds=args.folds, block_m=args.block, progress=True)
    names = [b.name for b in tsmrf.BOUNDS]
    kept = bool(v.kept[0])
    values = dict(zip(names, map(float, v.values[0]))) | {"window_m": float(v.window_m[0])}
    span = {b.name: b.hi - b.lo for b in tsmrf.BOUNDS}
    defaults = {b.name: b.default for b in tsmrf.BOUNDS}
    fitted = [k for k in names if kept and abs(values[k] - defaults[k]) > 1e-4 * span[k]]
    kind = "1 - kappa" if args.loss == "kappa" else "total error"
    validation = {"folds": args.folds, "block_m": args.block, "measure": kind,
                  "default": float(v.default_error[0]), "tuned": float(v.tuned_error[0]),
                  "kept": kept, "per_fold": v.fold_errors[:, 0, :].tolist()}
    extra = {"fitted": fitted, "grid": {"window_m": list(windows)},
             "window_chosen_from_grid": kept and values["window_m"] != Config().window_m,
             "not_differentiable": {"window_m": "loop count of the progressive opening: grid search"},
             "validation": validation, "loss": args.loss, "prior": args.prior, "steps": args.steps,
             "training_files": [str(p) for p in inputs]}
    write_params(out, method=args.method, values=values, units=tsmrf.UNITS, extra=extra)
    where = "held-out blocks" if args.folds >= 2 else "training points (no validation)"
    print(f"{out}: {args.method} " + ", ".join(f"{k}={values[k]:.4g}" for k in [*names, "window_m"]))
    print(f"validation on {where}: {kind} defaults {validation['default']:.4f}, tuned {validation['tuned']:.4f}"
          f" -> {'fitted values kept' if kept else 'defaults kept (tuning did not help)'}; "
          f"fitted: {', '.join(fitted) or 'none'}")
    return 0
