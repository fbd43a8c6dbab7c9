"""Tuning SMRF on the 11 ISPRS reference samples: protocols (a)-(e).

(a) defaults; (b) tuned per sample on its own labels (no prior, no validation: the papers'
protocol); (c) half split: tuned on the west half (x < median x) of each sample, scored on the
east half, and the reverse, with `gfjax tune`'s guard (`gfjax.tune.guard.validate`: prior,
k-fold by 50 m block of the training half, shrink level and sign-flip test against the
defaults); (d) leave-one-out across samples: one parameter set tuned on 10 samples with the
same guard, validated k-fold by sample over the 10, scored on the 11th; (e) gradient tuning vs a grid search of 5 values per parameter over the same bounds
and window grid, both scored on the hard total error, cost in forward-pass equivalents and
wall time.

    nice .venv/bin/python experiments/tune_isprs.py [--steps N] [--skip-loo]

The prepared problem (openings to 24 m of all 11 samples) is cached under --cache
(default /tmp/gfjax_tune_isprs), keyed by the data and the gfjax sources it depends on.

Writes experiments/results/tune_isprs_<phases>.json after every phase, and tune_isprs.md from
all such files (so (b)/(e) and (c)/(d) may run as two processes); `--method pmf` writes
tune_isprs_pmf_<phases>.json and tune_isprs_pmf.md; `--report-only` rewrites the .md alone.
The runs behind the committed results (one command each; the first prepares the cache):

    nice .venv/bin/python experiments/tune_isprs.py --phases abe --steps 40
    nice .venv/bin/python experiments/tune_isprs.py --phases c --steps 30 --folds 3
    nice .venv/bin/python experiments/tune_isprs.py --phases d --steps 30 --folds 3 --loo-folds 2 --loo-windows 18
    nice .venv/bin/python experiments/tune_isprs.py --method pmf --phases abecd --steps 60 --folds 3
    nice .venv/bin/python experiments/tune_isprs.py --method csf --phases abecd --steps 40 --folds 3 --check-filter --d-unguarded

MASF and DMF (`--method masf|dmf`) are tuned by grid search: this script hands them to
`experiments/tune_grid.py` (the same protocols from one table of labels per sample):

    nice .venv/bin/python experiments/tune_isprs.py --method masf
    nice .venv/bin/python experiments/tune_isprs.py --method dmf

CSF (`--method csf`): the class threshold is fitted by gradient; time step and rigidness
(grid `gfjax.csf.tuning.GRID`, 3 x 3 cloths) are searched on the grid, each cloth simulated
once per sample and its point-to-cloth distances cached under --cloth-cache (in a subfolder
keyed by the gfjax/csf sources, so a changed simulation is re-run). (e)'s grid is
5 thresholds x the same 9 cloths. `--check-filter` also runs `gfjax.csf.filter` on every
sample and records whether its labels equal the tuned pipeline's hard labels at the defaults.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import itertools
import json
import pickle
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import gfjax
from gfjax.bench.harness import Stopwatch
from gfjax.csf import tuning as tcsf
from gfjax.smrf import tuning as tsmrf
from gfjax.tune import fit as tfit
from gfjax.tune import guard
from gfjax.tune import tuners as tmethods
from gfjax.tune.problem import Problem, Sample

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "isprs_filtertest" / "reference"
NAMES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52",
         "samp54", "samp71"]
OUT = Path(__file__).resolve().parent / "results"


def pct(x):
    return f"{100 * x:.2f}"


def prepared(names: list[str], cache: Path, method: tmethods.GradientTuner = tsmrf.TUNER,
             cloth_cache: Path | None = None) -> tuple[Problem, float]:
    """The prepared `Problem` of the named samples, from a pickle under `cache` when one exists
    for the same files and gfjax sources (the openings to 24 m dominate the run otherwise);
    returns it and the seconds spent preparing it (read from the cache when loaded)."""
    files = [DATA / f"{n}-utm.laz" for n in names]
    key = hashlib.sha256()
    for f in files:
        key.update(f.read_bytes())
    deps = {"smrf": ("smrf", "raster", "io"), "pmf": ("pmf", "raster", "io"), "csf": ("csf", "io")}[method.name]
    for src in sorted((Path(gfjax.__file__).parent).glob("**/*.py")):
        if src.parent.name in deps or src.name in (f"{method.name}.py", "relax.py"):
            key.update(src.read_bytes())
    if method is tcsf.TUNER:
        key.update(repr(method.grid).encode())
    prefix = "problem" if method is tsmrf.TUNER else f"problem_{method.name}"
    path = cache / f"{prefix}_{key.hexdigest()[:16]}.pkl"
    if path.exists():
        with path.open("rb") as fh:
            problem, seconds = pickle.load(fh)
        return problem, seconds
    with Stopwatch() as watch:
        samples = [Sample.from_cloud(gfjax.read(f)) for f in files]
        with tcsf.cloth_cache(cloth_cache):
            problem = Problem(samples, config=method.config_type(), max_window_m=max(method.grid, default=None),
                              method=method, grid=method.grid if method is tcsf.TUNER else None)
    seconds = watch.wall_s
    cache.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with tmp.open("wb") as fh:
        pickle.dump((problem, seconds), fh)
    tmp.replace(path)
    return problem, seconds


def write_report(out: Path, method: tmethods.GradientTuner) -> None:
    """`<stem>.md` from every `<stem>_<phases>.json` of the method under `out` (merged in name order)."""
    stem = "tune_isprs" if method is tsmrf.TUNER else f"tune_isprs_{method.name}"
    merged: dict = {}
    commands = []
    for part in sorted(out.glob(f"{stem}_*.json")):
        if method is tsmrf.TUNER and any(part.name.startswith(f"tune_isprs_{m}_") for m in ("smrf", "pmf", "csf")):
            continue
        data = json.loads(part.read_text())
        commands.append(data["command"])
        merged.update(data)
    merged["command"] = "`; `".join(commands)
    (out / f"{stem}.md").write_text(report(merged))


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else list(argv)
    method = next((a.split("=", 1)[1] for a in args if a.startswith("--method=")), None)
    if "--method" in args[:-1]:
        method = args[args.index("--method") + 1]
    if method in ("masf", "dmf"):                   # searched on a grid: no gradient
        import tune_grid
        return tune_grid.main(args)
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--folds", type=int, default=2)
    ap.add_argument("--skip-loo", action="store_true")
    ap.add_argument("--samples", nargs="*", default=NAMES, help="subset (smoke tests)")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--phases", default="abecd", help="which of a, b, e, c, d to run")
    ap.add_argument("--method", default="smrf", choices=("smrf", "pmf", "csf"),
                    help="tuned method (pmf, csf: files tune_isprs_<method>_*; PMF's window series is not "
                         "searched; CSF's time step x rigidness grid is)")
    ap.add_argument("--loo-windows", default=None, help="static grid of (d) (default SMRF 12,18,24; CSF all cloths)")
    ap.add_argument("--cloth-cache", default="/tmp/gfjax_tune_csf_cloths", help="CSF: folder of cached cloths")
    ap.add_argument("--check-filter", action="store_true",
                    help="CSF: compare the hard labels at the defaults with gfjax.csf.filter on every sample")
    ap.add_argument("--cd-steps", type=int, default=None, help="steps of (c) and (d) (default --steps)")
    ap.add_argument("--loo-folds", type=int, default=None, help="folds (by sample) of (d)'s guard (default --folds)")
    ap.add_argument("--d-unguarded", action="store_true",
                    help="(d): also fit without the guard where the guard keeps the defaults (one more fit each)")
    ap.add_argument("--cache", default="/tmp/gfjax_tune_isprs", help="folder of the prepared-problem cache")
    ap.add_argument("--report-only", action="store_true", help="only rewrite the .md from the .json files")
    args = ap.parse_args(argv)
    if args.report_only:
        write_report(Path(args.out), tmethods.get(args.method))
        return 0
    jax.config.update("jax_compilation_cache_dir", "/tmp/gfjax_tune_cache")
    res: dict = {"command": "nice .venv/bin/python experiments/tune_isprs.py " + " ".join(sys.argv[1:]),
                 "device": f"{jax.devices()[0].platform} ({platform.processor() or platform.machine()})",
                 "jax": jax.__version__, "samples": list(args.samples)}
    out = Path(args.out)
    clock = Stopwatch()                        # the whole run: progress lines and `total_s`
    method = tmethods.get(args.method)
    stem = "tune_isprs" if method is tsmrf.TUNER else f"tune_isprs_{method.name}"
    res["method"] = method.name
    static_name = {"smrf": "window_m", "pmf": "max_window_m (fixed)", "csf": "cloth (10 rigidness + time_step)"}
    res["param_names"] = [b.name for b in method.bounds] + [static_name[method.name]]
    csf_sources = hashlib.sha256(b"".join(p.read_bytes() for p in
                                          sorted((Path(gfjax.__file__).parent / "csf").glob("*.py"))))
    cloth_cache = Path(args.cloth_cache) / csf_sources.hexdigest()[:12]
    problem, res["prepare_s"] = prepared(args.samples, Path(args.cache), method, cloth_cache)
    samples = problem.samples
    c = len(samples)
    per = np.arange(c, dtype=np.int32)
    defaults = np.tile(method.defaults, (c, 1))
    w0 = method.default_static(problem.config)                   # SMRF: the 18 m window
    all_masks = problem.masks()

    def save():
        (out / f"{stem}_{args.phases}.json").write_text(
            json.dumps(res, indent=1, default=lambda a: np.asarray(a).tolist()))
        write_report(out, method)
        print(f"[{clock.wall_s:.0f}s] saved", flush=True)

    # (a) defaults
    res["a_defaults"] = tfit.hard_errors(problem, defaults, all_masks, per, w0).tolist()
    if args.check_filter and method is tcsf.TUNER:
        hard = problem.labels(tfit.hard_ground(problem, defaults, per, w0))
        with Stopwatch() as watch:
            same = [bool(np.array_equal(h, gfjax.csf.filter(gfjax.read(DATA / f"{n}-utm.laz")).ground))
                    for h, n in zip(hard, args.samples)]
        res["a_equals_filter"] = {"labels_equal": same, "filter_s": watch.wall_s}
    save()
    if "b" not in args.phases:
        return cd(args, res, problem, samples, per, defaults, all_masks, save, clock)

    # timing of one hard evaluation and one value-and-grad call (all 11 samples), warm.
    radius = jnp.asarray(method.static_px(problem.config, w0), jnp.int32)
    arrays = tfit._arrays(problem)
    raw = jnp.zeros((c, len(method.bounds)), jnp.float32)
    args_vg = (raw, radius, jnp.float32(0.1), arrays, all_masks, jnp.asarray(per), jnp.ones(c, jnp.float32),
               jnp.float32(0.0))
    kw = dict(config=problem.config, kind="total-error", n_samples=c, method=method)
    jax.block_until_ready(tfit._soft_value_and_grad(*args_vg, **kw))
    tfit.hard_errors(problem, defaults, all_masks, per, w0)
    reps = 5
    with Stopwatch() as watch:
        for _ in range(reps):
            jax.block_until_ready(tfit._soft_value_and_grad(*args_vg, **kw))
    t_vg = watch.wall_s / reps
    with Stopwatch() as watch:
        for _ in range(reps):
            tfit.hard_errors(problem, defaults, all_masks, per, w0)
    t_hard = watch.wall_s / reps
    res["timing"] = {"hard_eval_s": t_hard, "value_and_grad_s": t_vg, "grad_in_forward_passes": t_vg / t_hard}
    save()

    # (b) per sample, own labels, no prior, no validation
    settings_b = tfit.Settings(steps=args.steps, prior=0.0)
    with Stopwatch() as watch:
        fb = tfit.fit(problem, settings_b, group=per)
    wall_b = watch.wall_s
    res["b_tuned"] = tfit.hard_errors_at(problem, fb.values, fb.window_m, all_masks, per).tolist()
    res["b_values"] = fb.values
    res["b_window_m"] = fb.window_m
    res["b_cost"] = {"gradient_calls": fb.gradient_calls, "hard_evaluations": fb.hard_evaluations,
                     "forward_equivalents": fb.gradient_calls * t_vg / t_hard + fb.hard_evaluations,
                     "wall_s": wall_b}
    res["b_history"] = {str(w): {"loss": h["loss"], "values": h["values"]} for w, h in fb.history.items()}
    save()

    # (e) grid search: 5 values per parameter over the same bounds, the same window grid.
    grids = [np.linspace(b.lo, b.hi, 5) for b in method.bounds]
    best = np.full(c, np.inf)
    best_at = np.zeros((c, len(method.bounds) + 1))
    n_eval = 0
    with Stopwatch() as watch:
        for w in method.grid_values(problem.config, None):
            for combo in itertools.product(*grids):
                vals = np.tile(np.asarray(combo, np.float32), (c, 1))
                errs = tfit.hard_errors(problem, vals, all_masks, per, w)
                n_eval += 1
                better = errs < best
                best = np.where(better, errs, best)
                best_at[better] = [*combo, w]
    res["e_grid"] = {"best": best.tolist(), "best_at": best_at, "evaluations": n_eval,
                     "forward_equivalents": n_eval, "wall_s": watch.wall_s}
    save()

    if "c" in args.phases or "d" in args.phases:
        return cd(args, res, problem, samples, per, defaults, all_masks, save, clock)
    res["total_s"] = clock.wall_s
    save()
    return 0


def cd(args, res, problem, samples, per, defaults, all_masks, save, clock: Stopwatch) -> int:
    c = len(samples)
    w0 = problem.method.default_static(problem.config)
    # (c) half split with the tool's guard (`gfjax.tune.guard.validate`): per sample, k-fold
    # by 50 m block of the training half, sign-flip test against the defaults.
    settings = tfit.Settings(steps=args.cd_steps or args.steps)
    res["cd_settings"] = {"steps": settings.steps, "prior": settings.prior, "folds": args.folds,
                          "block_m": 50.0, "alpha": 0.05, "shrink": list(guard.SHRINK),
                          "loo_windows": args.loo_windows, "loo_folds": args.loo_folds or args.folds}
    if "c" in args.phases:
        res["c"] = {}
    for train_side in (("west", "east") if "c" in args.phases else ()):
        halves = []
        for s in samples:
            west = s.xyz_m[:, 0] < np.median(s.xyz_m[s.use, 0])
            halves.append(west if train_side == "west" else ~west)
        test_masks = problem.masks([~h for h in halves])
        v = guard.validate(problem, settings, point_masks=halves, group=per, folds=args.folds, block_m=50.0)
        unguarded = v.fit if v.fit is not None else tfit.fit(problem, settings, masks=problem.masks(halves), group=per)
        res["c"][train_side] = {
            "defaults": tfit.hard_errors(problem, defaults, test_masks, per, w0).tolist(),
            "guarded": tfit.hard_errors_at(problem, v.values, v.window_m, test_masks, per).tolist(),
            "unguarded": tfit.hard_errors_at(problem, unguarded.values, unguarded.window_m, test_masks, per).tolist(),
            "kept": v.kept, "values": v.values, "window_m": v.window_m, "shrink": v.shrink,
            "p_value": v.p_value, "units": v.units,
            "val_default": v.default_error, "val_tuned": v.tuned_error}
        save()

    # (d) leave one sample out: one shared set tuned on 10 samples with the guard (k-fold by
    # sample over the 10), scored on the 11th.
    if "d" in args.phases and not args.skip_loo:
        loo_windows = args.loo_windows or ("12,18,24" if problem.method is tsmrf.TUNER else None)
        loo = dataclasses.replace(settings, windows_m=tuple(float(w) for w in loo_windows.split(","))
                                  if loo_windows else None)
        res["d"] = {"defaults": res["a_defaults"], "tuned": [], "unguarded": [], "values": [], "window_m": [],
                    "kept": [], "p_value": [], "val_default": [], "val_tuned": []}
        for i in range(c):
            weight = np.where(per == i, 0.0, 1.0 / (c - 1))
            shared = np.zeros(c, np.int32)
            v = guard.validate(problem, loo, group=shared, weight=weight, folds=args.loo_folds or args.folds)
            runs = [("tuned", v.values, v.window_m)]
            if v.fit is not None or args.d_unguarded:
                f = v.fit if v.fit is not None else tfit.fit(problem, loo, group=shared, weight=weight)
                runs.append(("unguarded", f.values, f.window_m))
            for key, vals, win in runs:
                err = tfit.hard_errors_at(problem, np.tile(vals, (c, 1)), np.repeat(win, c), all_masks, per)
                res["d"][key].append(float(err[i]))
            res["d"]["values"].append(v.values[0])
            res["d"]["window_m"].append(float(v.window_m[0]))
            res["d"]["kept"].append(bool(v.kept[0]))
            res["d"]["p_value"].append(float(v.p_value[0]))
            res["d"]["val_default"].append(float(v.default_error[0]))
            res["d"]["val_tuned"].append(float(v.tuned_error[0]))
            save()
    res["total_s"] = clock.wall_s
    save()
    return 0


def report(res: dict) -> str:
    names = res["samples"]
    method = res.get("method", "smrf")
    pnames = ", ".join(res.get("param_names", ["slope", "threshold_m", "scalar", "window_m"]))
    lines = [f"# {method.upper()} tuning on the 11 ISPRS reference samples (protocols a-e)", "",
             f"Command: `{res['command']}`  ", f"Device: {res['device']}, JAX {res['jax']}. "
             "Total error in percent (hard labels, plain-filter pipeline), unweighted mean over samples.", ""]
    cols, header = [], ["sample"]
    if "a_defaults" in res:
        cols.append(res["a_defaults"])
        header.append("(a) defaults")
    if "b_tuned" in res:
        cols.append(res["b_tuned"])
        header.append("(b) tuned, own labels")
    if "e_grid" in res:
        cols.append(res["e_grid"]["best"])
        header.append("(e) grid best, own labels")
    for side in ("west", "east"):
        if side in res.get("c", {}):
            r = res["c"][side]
            test = "east" if side == "west" else "west"
            cols += [r["defaults"], r["guarded"], r["unguarded"]]
            header += [f"(c) {test} half: defaults", f"(c) {test}: tuned on {side}, guarded",
                       f"(c) {test}: unguarded"]
    if "d" in res and len(res["d"]["tuned"]) == len(names):
        cols.append(res["d"]["tuned"])
        header.append("(d) leave-one-out, guarded")
        if len(res["d"].get("unguarded", [])) == len(names):
            cols.append(res["d"]["unguarded"])
            header.append("(d) unguarded")
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "---|" * len(header))
    for i, n in enumerate(names):
        lines.append(f"| {n} | " + " | ".join(pct(col[i]) for col in cols) + " |")
    lines.append("| **mean** | " + " | ".join(f"**{pct(np.mean(col))}**" for col in cols) + " |")
    lines.append("")
    if "c" in res and res["c"]:
        for side, r in res["c"].items():
            better = int(np.sum(np.asarray(r["guarded"]) < np.asarray(r["defaults"]) - 1e-12))
            worse = int(np.sum(np.asarray(r["guarded"]) > np.asarray(r["defaults"]) + 1e-12))
            lines.append(f"(c) tuned on {side}: guard kept the fit on {int(np.sum(r['kept']))} of "
                         f"{len(names)} samples; better than defaults on {better}, worse on {worse}.")
            if "p_value" in r:
                lines.append("")
                lines.append(f"(c) guard on {side} (out-of-fold total error on the {side} half: defaults -> "
                             "chosen level; level a on the segment defaults -> fit; sign-flip p over changed "
                             "50 m blocks, Bonferroni x3): " + "; ".join(
                                 f"{n}: {pct(d)} -> {pct(t)}, p={p:.3g}/{u} blocks" + (f", kept a={a:.2f}" if k else "")
                                 for n, d, t, p, u, k, a in zip(names, r["val_default"], r["val_tuned"], r["p_value"],
                                                               r["units"], r["kept"], r["shrink"])))
            lines.append("")
        lines.append("")
    if len(res.get("c", {})) == 2:
        both = [np.mean([res["c"][side][col] for side in ("west", "east")], axis=0) for col in ("defaults", "guarded")]
        better = int(np.sum(both[1] < both[0] - 1e-12))
        worse = int(np.sum(both[1] > both[0] + 1e-12))
        lines.append(f"(c) both directions (per sample, the mean of its two test halves): guarded {pct(np.mean(both[1]))} "
                     f"vs defaults {pct(np.mean(both[0]))}; better on {better} of {len(names)} samples, worse on {worse}.")
        lines.append("")
    if "d" in res and res["d"].get("p_value"):
        d = res["d"]
        lines.append(f"(d) guard (k-fold by sample over the 10 training samples): kept on {sum(d['kept'])} of "
                     f"{len(d['kept'])} left-out samples; out-of-fold mean total error defaults -> tuned, p: " + "; ".join(
                         f"{names[i]}: {pct(a)} -> {pct(b)}, p={p:.3g}" for i, (a, b, p) in
                         enumerate(zip(d["val_default"], d["val_tuned"], d["p_value"]))))
        lines.append("")
    if "d" in res and res["d"]["tuned"]:
        lines.append(f"(d) shared values per left-out sample ({pnames}): " + "; ".join(
            f"{names[i]}: {', '.join(f'{x:.3f}' for x in v)}, {w:g}"
            for i, (v, w) in enumerate(zip(res["d"]["values"], res["d"]["window_m"]))))
        lines.append("")
    if "timing" in res:
        t = res["timing"]
        prepared_what = "cloth distances" if method == "csf" else "openings"
        lines.append(f"Cost unit: one hard evaluation of all 11 samples from the prepared {prepared_what} = "
                     f"{t['hard_eval_s']:.3f} s; one relaxed value-and-grad call = {t['value_and_grad_s']:.3f} s "
                     f"= {t['grad_in_forward_passes']:.2f} forward passes (measured, warm).")
        lines.append("")
    if "b_cost" in res and "e_grid" in res:
        b, e = res["b_cost"], res["e_grid"]
        lines.append("(e) gradient tuning vs grid search, both on all 11 samples at once, own labels:")
        lines.append("")
        lines.append("| | mean total error | forward-pass equivalents | wall time [s] |")
        lines.append("|---|---|---|---|")
        static = "cloths" if method == "csf" else "windows"
        n_fitted = len(res["b_values"][0])
        lines.append(f"| gradient (Adam, {len(res['b_history'])} {static}) | {pct(np.mean(res['b_tuned']))} | "
                     f"{b['forward_equivalents']:.0f} ({b['gradient_calls']} grad + {b['hard_evaluations']} hard) | "
                     f"{b['wall_s']:.0f} |")
        lines.append(f"| grid {'x'.join(['5'] * n_fitted)} x {static} | {pct(np.mean(e['best']))} | {e['forward_equivalents']} | "
                     f"{e['wall_s']:.0f} |")
        lines.append("")
        lines.append(f"(b) fitted values ({pnames}): " + "; ".join(
            f"{n}: {', '.join(f'{x:.3f}' for x in v)}, {w:g}"
            for n, v, w in zip(names, res["b_values"], res["b_window_m"])))
        lines.append("")
        lines.append("(e) grid optimum: " + "; ".join(
            f"{n}: {', '.join(f'{x:.3g}' for x in v)}" for n, v in zip(names, res["e_grid"]["best_at"])))
    if "prepare_s" in res:
        lines.append("")
        what = ("9 cloths per sample simulated (or read from the cloth cache), distances, compile" if method == "csf"
                else "rasters, openings up to the largest window, compile")
        lines.append(f"Reading and preparing ({what}): {res['prepare_s']:.0f} s.")
    if "a_equals_filter" in res:
        same = res["a_equals_filter"]["labels_equal"]
        lines.append("")
        filter_s = res["a_equals_filter"]["filter_s"]
        lines.append(f"Hard labels at the defaults equal `gfjax.csf.filter`'s on {sum(same)} of {len(same)} samples "
                     f"(filter runs: {filter_s:.0f} s).")
        if "b_cost" in res and "e_grid" in res:
            n_cloths = len(res["b_history"])
            lines.append("")
            lines.append(f"CSF cost: (b) and (e) share the {n_cloths} cloths per sample simulated once in the "
                         f"preparation; one plain-filter run of the {len(same)} samples (one cloth each, same run) took "
                         f"{filter_s:.0f} s, so the cloths cost about {n_cloths} x {filter_s:.0f} s, against "
                         f"{res['b_cost']['wall_s']:.0f} s of gradient tuning and {res['e_grid']['wall_s']:.0f} s of grid search "
                         "on the cached distances.")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
