"""Tuning SMRF on the 11 ISPRS reference samples: protocol (a)-(e) of issue 9.

(a) defaults; (b) tuned per sample on its own labels (no prior, no validation: the papers'
protocol); (c) half split: tuned on the west half (x < median x) of each sample, scored on the
east half, and the reverse, with `gfjax tune`'s guard (prior + k-fold block validation);
(d) leave-one-out across samples: one parameter set tuned on 10 samples (prior), scored on
the 11th; (e) gradient tuning vs a grid search of 5 values per parameter over the same bounds
and window grid, both scored on the hard total error, cost in forward-pass equivalents and
wall time.

    nice .venv/bin/python experiments/tune_isprs.py [--steps N] [--skip-loo]

Writes experiments/results/tune_isprs_<phases>.json after every phase, and tune_isprs.md from
all such files (so (b)/(e) and (c)/(d) may run as two processes).
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import gfjax
from gfjax.smrf import Config
from gfjax.tune import fit as tfit
from gfjax.tune import smrf as tsmrf
from gfjax.tune.problem import Problem, Sample

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "isprs_filtertest" / "reference"
NAMES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52",
         "samp54", "samp71"]
OUT = Path(__file__).resolve().parent / "results"


def pct(x):
    return f"{100 * x:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--folds", type=int, default=2)
    ap.add_argument("--skip-loo", action="store_true")
    ap.add_argument("--samples", nargs="*", default=NAMES, help="subset (smoke tests)")
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--phases", default="abecd", help="which of a, b, e, c, d to run")
    ap.add_argument("--loo-windows", default="12,18,24", help="window grid of (d)")
    ap.add_argument("--cd-steps", type=int, default=None, help="steps of (c) and (d) (default --steps)")
    args = ap.parse_args(argv)
    jax.config.update("jax_compilation_cache_dir", "/tmp/gfjax_tune_cache")
    res: dict = {"command": "nice .venv/bin/python experiments/tune_isprs.py " + " ".join(sys.argv[1:]),
                 "device": f"{jax.devices()[0].platform} ({platform.processor() or platform.machine()})",
                 "jax": jax.__version__, "samples": list(args.samples)}
    out = Path(args.out)
    t0 = time.perf_counter()
    samples = [Sample.from_cloud(gfjax.read(DATA / f"{n}-utm.laz")) for n in args.samples]
    c = len(samples)
    problem = Problem(samples, config=Config(), max_window_m=max(tsmrf.GRID["window_m"]))
    res["prepare_s"] = time.perf_counter() - t0
    per = np.arange(c, dtype=np.int32)
    defaults = np.tile(tfit.DEFAULTS, (c, 1))
    all_masks = problem.masks()

    def save():
        (out / f"tune_isprs_{args.phases}.json").write_text(
            json.dumps(res, indent=1, default=lambda a: np.asarray(a).tolist()))
        merged: dict = {}
        commands = []
        for part in sorted(out.glob("tune_isprs_*.json")):
            data = json.loads(part.read_text())
            commands.append(data["command"])
            merged.update(data)
        merged["command"] = "`; `".join(commands)
        (out / "tune_isprs.md").write_text(report(merged))
        print(f"[{time.perf_counter() - t0:.0f}s] saved", flush=True)

    # (a) defaults
    res["a_defaults"] = tfit.hard_errors(problem, defaults, all_masks, per, 18.0).tolist()
    save()
    if "b" not in args.phases:
        return cd(args, res, problem, samples, per, defaults, all_masks, save, t0)

    # timing of one hard evaluation and one value-and-grad call (all 11 samples), warm.
    radius = jnp.asarray(tsmrf.radius_for(problem.config, 18.0), jnp.int32)
    arrays = tfit._arrays(problem)
    raw = jnp.zeros((c, 3), jnp.float32)
    args_vg = (raw, radius, jnp.float32(0.1), arrays, all_masks, jnp.asarray(per), jnp.ones(c, jnp.float32),
               jnp.float32(0.0))
    kw = dict(config=problem.config, kind="total-error", n_samples=c)
    jax.block_until_ready(tfit._soft_value_and_grad(*args_vg, **kw))
    tfit.hard_errors(problem, defaults, all_masks, per, 18.0)
    reps = 5
    t = time.perf_counter()
    for _ in range(reps):
        jax.block_until_ready(tfit._soft_value_and_grad(*args_vg, **kw))
    t_vg = (time.perf_counter() - t) / reps
    t = time.perf_counter()
    for _ in range(reps):
        tfit.hard_errors(problem, defaults, all_masks, per, 18.0)
    t_hard = (time.perf_counter() - t) / reps
    res["timing"] = {"hard_eval_s": t_hard, "value_and_grad_s": t_vg, "grad_in_forward_passes": t_vg / t_hard}
    save()

    # (b) per sample, own labels, no prior, no validation
    settings_b = tfit.Settings(steps=args.steps, prior=0.0)
    t = time.perf_counter()
    fb = tfit.fit(problem, settings_b, group=per)
    wall_b = time.perf_counter() - t
    res["b_tuned"] = tfit.hard_errors_at(problem, fb.values, fb.window_m, all_masks, per).tolist()
    res["b_values"] = fb.values
    res["b_window_m"] = fb.window_m
    res["b_cost"] = {"gradient_calls": fb.gradient_calls, "hard_evaluations": fb.hard_evaluations,
                     "forward_equivalents": fb.gradient_calls * t_vg / t_hard + fb.hard_evaluations,
                     "wall_s": wall_b}
    res["b_history"] = {str(w): {"loss": h["loss"], "values": h["values"]} for w, h in fb.history.items()}
    save()

    # (e) grid search: 5 values per parameter over the same bounds, the same window grid.
    grids = [np.linspace(b.lo, b.hi, 5) for b in tsmrf.BOUNDS]
    best = np.full(c, np.inf)
    best_at = np.zeros((c, 4))
    t = time.perf_counter()
    n_eval = 0
    for w in tsmrf.GRID["window_m"]:
        for combo in itertools.product(*grids):
            vals = np.tile(np.asarray(combo, np.float32), (c, 1))
            errs = tfit.hard_errors(problem, vals, all_masks, per, w)
            n_eval += 1
            better = errs < best
            best = np.where(better, errs, best)
            best_at[better] = [*combo, w]
    res["e_grid"] = {"best": best.tolist(), "best_at": best_at, "evaluations": n_eval,
                     "forward_equivalents": n_eval, "wall_s": time.perf_counter() - t}
    save()

    if "c" in args.phases or "d" in args.phases:
        return cd(args, res, problem, samples, per, defaults, all_masks, save, t0)
    res["total_s"] = time.perf_counter() - t0
    save()
    return 0


def cd(args, res, problem, samples, per, defaults, all_masks, save, t0) -> int:
    c = len(samples)
    # (c) half split with the tool's guard: prior + k-fold block validation, per sample.
    settings = tfit.Settings(steps=args.cd_steps or args.steps)
    res["cd_settings"] = {"steps": settings.steps, "prior": settings.prior, "folds": args.folds,
                          "block_m": 50.0, "loo_windows": args.loo_windows}
    res["c"] = {}
    for train_side in (("west", "east") if "c" in args.phases else ()):
        halves = []
        for s in samples:
            west = s.xyz_m[:, 0] < np.median(s.xyz_m[s.use, 0])
            halves.append(west if train_side == "west" else ~west)
        test_masks = problem.masks([~h for h in halves])
        v = tfit.validate(problem, settings, point_masks=halves, group=per, folds=args.folds, block_m=50.0)
        res["c"][train_side] = {
            "defaults": tfit.hard_errors(problem, defaults, test_masks, per, 18.0).tolist(),
            "guarded": tfit.hard_errors_at(problem, v.values, v.window_m, test_masks, per).tolist(),
            "unguarded": tfit.hard_errors_at(problem, v.fit.values, v.fit.window_m, test_masks, per).tolist(),
            "kept": v.kept, "values": v.values, "window_m": v.window_m,
            "val_default": v.default_error, "val_tuned": v.tuned_error}
        save()

    # (d) leave one sample out: one shared set tuned on 10 samples (prior), scored on the 11th.
    if "d" in args.phases and not args.skip_loo:
        loo = dataclasses.replace(settings, windows_m=tuple(float(w) for w in args.loo_windows.split(",")))
        res["d"] = {"defaults": res["a_defaults"], "tuned": [], "values": [], "window_m": []}
        for i in range(c):
            weight = np.where(per == i, 0.0, 1.0 / (c - 1))
            f = tfit.fit(problem, loo, group=np.zeros(c, np.int32), weight=weight)
            err = tfit.hard_errors_at(problem, np.tile(f.values, (c, 1)), np.repeat(f.window_m, c), all_masks, per)
            res["d"]["tuned"].append(float(err[i]))
            res["d"]["values"].append(f.values[0])
            res["d"]["window_m"].append(float(f.window_m[0]))
            save()
    res["total_s"] = time.perf_counter() - t0
    save()
    return 0


def report(res: dict) -> str:
    names = res["samples"]
    lines = ["# SMRF tuning on the 11 ISPRS reference samples (issue 9, protocol a-e)", "",
             f"Command: `{res['command']}`  ", f"Device: {res['device']}, JAX {res['jax']}. "
             "Total error in percent (hard labels, plain-filter pipeline), unweighted mean over samples.", ""]
    cols, header = [], ["sample"]
    if "a_defaults" in res:
        cols.append(res["a_defaults"]); header.append("(a) defaults")
    if "b_tuned" in res:
        cols.append(res["b_tuned"]); header.append("(b) tuned, own labels")
    if "e_grid" in res:
        cols.append(res["e_grid"]["best"]); header.append("(e) grid best, own labels")
    for side in ("west", "east"):
        if side in res.get("c", {}):
            r = res["c"][side]
            test = "east" if side == "west" else "west"
            cols += [r["defaults"], r["guarded"], r["unguarded"]]
            header += [f"(c) {test} half: defaults", f"(c) {test}: tuned on {side}, guarded",
                       f"(c) {test}: unguarded"]
    if "d" in res and len(res["d"]["tuned"]) == len(names):
        cols.append(res["d"]["tuned"]); header.append("(d) leave-one-out")
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
        lines.append("")
    if "d" in res and res["d"]["tuned"]:
        lines.append("(d) shared values per left-out sample (slope, threshold_m, scalar, window_m): " + "; ".join(
            f"{names[i]}: {', '.join(f'{x:.3f}' for x in v)}, {w:g}"
            for i, (v, w) in enumerate(zip(res["d"]["values"], res["d"]["window_m"]))))
        lines.append("")
    if "timing" in res:
        t = res["timing"]
        lines.append(f"Cost unit: one hard evaluation of all 11 samples from the prepared openings = "
                     f"{t['hard_eval_s']:.3f} s; one relaxed value-and-grad call = {t['value_and_grad_s']:.3f} s "
                     f"= {t['grad_in_forward_passes']:.2f} forward passes (measured, warm).")
        lines.append("")
    if "b_cost" in res and "e_grid" in res:
        b, e = res["b_cost"], res["e_grid"]
        lines.append("(e) gradient tuning vs grid search, both on all 11 samples at once, own labels:")
        lines.append("")
        lines.append("| | mean total error | forward-pass equivalents | wall time [s] |")
        lines.append("|---|---|---|---|")
        lines.append(f"| gradient (Adam, {len(res['b_history'])} windows) | {pct(np.mean(res['b_tuned']))} | "
                     f"{b['forward_equivalents']:.0f} ({b['gradient_calls']} grad + {b['hard_evaluations']} hard) | "
                     f"{b['wall_s']:.0f} |")
        lines.append(f"| grid 5x5x5 x windows | {pct(np.mean(e['best']))} | {e['forward_equivalents']} | "
                     f"{e['wall_s']:.0f} |")
        lines.append("")
        lines.append("(b) fitted values (slope, threshold_m, scalar, window_m): " + "; ".join(
            f"{n}: {', '.join(f'{x:.3f}' for x in v)}, {w:g}"
            for n, v, w in zip(names, res["b_values"], res["b_window_m"])))
        lines.append("")
        lines.append("(e) grid optimum: " + "; ".join(
            f"{n}: {', '.join(f'{x:.3g}' for x in v)}" for n, v in zip(names, res["e_grid"]["best_at"])))
    if "prepare_s" in res:
        lines.append("")
        lines.append(f"Reading and preparing (ZImin, low outliers, openings to 24 m, compile): {res['prepare_s']:.0f} s.")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
