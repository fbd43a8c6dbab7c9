"""MASF or DMF tuned by grid search on the 11 ISPRS reference samples: the protocols of the SMRF
tuning experiment, from one table per sample.

    nice .venv/bin/python experiments/tune_grid.py --method masf|dmf [--samples samp12 ...] [--folds 3]

Each sample is labelled once with every candidate of the method's grid (`gfjax.masf.tuning.GRID`:
480 MASF runs on one preparation; `gfjax.dmf.tuning.GRID`: 675 DMF final rules on 45
preparations), by `wrong_table`, whose defaults' row is the plain filter's errors (checked
here on every sample); every protocol is then a choice over those tables (`gfjax.tune.search`):

(a) defaults;
(p) MASF: the paper's per-sample values (Table 3; `masf.PRESETS["paper-sampNN"]`, run by the filter);
(b) the best candidate on the sample's own labels, scored on them (in-sample);
(g) guarded: the one-standard-error rule's candidate (the nearest the defaults among those
    within one standard error plus a margin of ties of the best), kept only where 3 folds of 50 m blocks of the
    sample and the sign-flip test say it helps, scored on all its labels;
(c) half split: tuned on the west half's labels (x below the median), guarded, scored on the
    east half, and the other way round; the filter always runs on the whole sample;
(d) leave-one-out: tuned on the other 10 samples (guarded by sample, 3 folds), scored on the
    left-out one.

Then (g) and (c) again for each margin of ties in `--margins` (the rule's is
`search.TIE_MARGIN`). Writes `experiments/results/tune_isprs_<method>.md` (and `.json`).
Tables are cached in `--cache`.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np

import gfjax
from gfjax import dmf, masf
from gfjax.bench.harness import Stopwatch
from gfjax.dmf import tuning as tdmf
from gfjax.masf import tuning as tmasf
from gfjax.tune import search
from gfjax.tune.problem import Sample

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS = DATA / "isprs_filtertest" / "reference"
NAMES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52", "samp54", "samp71"]
RESULTS = ROOT / "experiments" / "results"
METHODS = {"masf": (masf, tmasf), "dmf": (dmf, tdmf)}


def pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.2f}"


def table(method: str, sample: Sample, combos, cache: Path) -> tuple[np.ndarray, float]:
    """The sample's table of mislabelled points per candidate and the seconds it took to make
    (cached in `cache`)."""
    key = hashlib.sha256(json.dumps([method, sample.name, combos, gfjax.__version__]).encode()).hexdigest()[:16]
    path = cache / f"{method}-{sample.name}-{key}.npy"
    seconds = path.with_suffix(".seconds")
    if path.exists() and seconds.exists():
        return np.load(path), float(seconds.read_text())
    with Stopwatch() as watch:
        module, tmodule = METHODS[method]
        wrong = tmodule.TUNER.wrong_table(sample, module.Config(), combos)
    took = watch.wall_s
    print(f"{sample.name}: {len(combos)} runs in {took:.0f} s", flush=True)
    np.save(path, wrong)
    seconds.write_text(f"{took:.1f}")
    return wrong, took


def error(wrong_row: np.ndarray, mask: np.ndarray) -> float:
    return float(wrong_row[mask].mean())


def halves(sample: Sample) -> tuple[np.ndarray, np.ndarray]:
    """The sample's used points west and east of their median x."""
    use = sample.use
    west = use & (sample.xyz_m[:, 0] < np.median(sample.xyz_m[use, 0]))
    return west, use & ~west


def margin_sweep(samples, wrong, default: int, distance: np.ndarray, args, margins) -> list[dict]:
    """(g) and (c) again for each margin of ties of the rule (`search.TIE_MARGIN`)."""
    out = []
    for margin in margins:
        kw = dict(default=default, distance=distance, folds=args.folds, block_m=args.block, alpha=args.alpha,
                  margin=margin)
        own, tuned, base = [], [], []
        for s, w in zip(samples, wrong):
            own.append(error(w[search.validate([w], [s.xyz_m], [s.use], **kw).index], s.use))
            west, east = halves(s)
            pairs = [(error(w[search.validate([w], [s.xyz_m], [train], **kw).index], test), error(w[default], test))
                     for train, test in ((west, east), (east, west))]
            tuned.append([t for t, _ in pairs])
            base.append([d for _, d in pairs])
        tuned, base = np.array(tuned), np.array(base)
        by_sample = tuned.mean(axis=1) - base.mean(axis=1)
        out.append({"margin": margin, "own_guarded": float(np.mean(own)), "halves_tuned": float(tuned.mean()),
                    "halves_default": float(base.mean()), "worst_sample": float(by_sample.max()),
                    "worst_half": float((tuned - base).max()), "better": int(np.sum(by_sample < 0)),
                    "worse": int(np.sum(by_sample > 0))})
        print(f"margin {margin:g}: {out[-1]}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=tuple(METHODS), default="masf")
    ap.add_argument("--samples", nargs="*", default=NAMES)
    ap.add_argument("--folds", type=int, default=3)
    ap.add_argument("--block", type=float, default=50.0)
    ap.add_argument("--alpha", type=float, default=0.05)
    ap.add_argument("--cache", default="/tmp/gfjax_tune_grid")
    ap.add_argument("--margins", default="0,0.001,0.002,0.003,0.004,0.005,0.01",
                    help="margins of ties for the sweep of (g) and (c) (the rule's default: search.TIE_MARGIN)")
    ap.add_argument("--out", default=None, help="default experiments/results/tune_isprs_<method>.md")
    args = ap.parse_args(argv)
    cache = Path(args.cache)
    cache.mkdir(parents=True, exist_ok=True)
    module, tmodule = METHODS[args.method]
    combos, default = tmodule.candidates(module.Config())
    distance = search.grid_distance(combos, default)
    samples, wrong, paper, table_s = [], [], {}, 0.0
    for name in args.samples:
        cloud = gfjax.read(ISPRS / f"{name}-utm.laz")
        sample = Sample.from_cloud(cloud)._replace(name=name)
        w, took = table(args.method, sample, combos, cache)
        table_s += took
        plain = module.filter(cloud).ground != sample.ref_ground
        assert np.array_equal(w[default], plain), f"{name}: the defaults' row differs from {args.method}.filter"
        if args.method == "masf":
            config, params = gfjax.methods.make_config_and_params(masf, preset=f"paper-{name}")
            paper[name] = error(masf.filter(cloud, config=config, params=params).ground != sample.ref_ground,
                                sample.use)
        samples.append(sample)
        wrong.append(w)

    rows, choices = [], {}
    for i, (s, w) in enumerate(zip(samples, wrong)):
        use = s.use
        west, east = halves(s)
        own = search.validate([w], [s.xyz_m], [use], default=default, folds=1)
        guarded = search.validate([w], [s.xyz_m], [use], default=default, distance=distance, folds=args.folds,
                                  block_m=args.block, alpha=args.alpha)
        by_half = {}
        for train, test, label in ((west, east, "east"), (east, west, "west")):
            c = search.validate([w], [s.xyz_m], [train], default=default, distance=distance, folds=args.folds,
                                block_m=args.block, alpha=args.alpha)
            by_half[label] = {"default": error(w[default], test), "guarded": error(w[c.index], test),
                             "unguarded": error(w[c.best], test), "kept": c.kept, "p": c.p_value,
                             "choice": combos[c.index]}
        others = [j for j in range(len(samples)) if j != i]
        loo = None
        if others:
            c = search.validate([wrong[j] for j in others], [samples[j].xyz_m for j in others],
                                [samples[j].use for j in others], default=default, distance=distance,
                                folds=min(args.folds, len(others)), alpha=args.alpha)
            loo = {"guarded": error(w[c.index], use), "unguarded": error(w[c.best], use), "kept": c.kept,
                   "p": c.p_value, "choice": combos[c.index], "best": combos[c.best]}
        rows.append({"sample": s.name, "default": error(w[default], use), "paper": paper.get(s.name),
                     "own": error(w[own.best], use), "own_choice": combos[own.best],
                     "guarded": error(w[guarded.index], use), "guarded_kept": guarded.kept, "guarded_p": guarded.p_value,
                     "guarded_choice": combos[guarded.index], "halves": by_half, "loo": loo})
        choices[s.name] = combos[own.best]
    sweep = margin_sweep(samples, wrong, default, distance, args, [float(m) for m in args.margins.split(",") if m])
    result = {"method": args.method, "margin": search.TIE_MARGIN, "sweep": sweep, "grid": {k: sorted({c[k] for c in combos}) for k in combos[0]}, "candidates": len(combos),
              "folds": args.folds, "block_m": args.block, "alpha": args.alpha, "rows": rows,
              "table_seconds": table_s, "samples": args.samples}
    out = Path(args.out) if args.out else RESULTS / f"tune_isprs_{args.method}.md"
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.write_text(report(result, sys.argv[1:] if argv is None else argv))
    print(out.read_text())
    return 0


def report(res: dict, argv) -> str:
    rows = res["rows"]

    def mean(values):
        return "-" if any(v is None for v in values) else pct(float(np.mean(values)))

    name = res["method"].upper()
    has_paper = all(r["paper"] is not None for r in rows)
    lines = [f"# {name} tuned by grid search on the 11 ISPRS reference samples", "",
             "Command: `nice .venv/bin/python experiments/tune_grid.py"
             + (" " + " ".join(argv) if argv else "") + "`  ",
             f"Grid ({res['candidates']} candidates, every combination): "
             + "; ".join(f"{k} {', '.join(f'{v:g}' for v in vals)}" for k, vals in res["grid"].items())
             + f". Guarded choices (g, c, d): the one-standard-error rule toward the defaults with a margin of ties "
             f"of {100 * res['margin']:g} points (`gfjax.tune.search`), "
             f"{res['folds']} folds of {res['block_m']:g} m blocks (one sample) or of samples (d), "
             f"sign-flip test at {res['alpha']:g}. Labelling every sample with every candidate took "
             f"{res['table_seconds']:.0f} s (2-core CPU, shared).", "",
             "Total error in percent over each sample's used points (unweighted mean over samples). (a) defaults; "
             + ("(p) the paper's per-sample values (Table 3); " if has_paper else "") + "(b) the best candidate on the sample's own labels "
             "(in-sample); (g) the same guarded; (c) tuned on one half (x below / above the median), guarded, "
             "scored on the other; (d) tuned on the other 10 samples, guarded, scored on the left-out one.", "",
             "| sample | (a) defaults | (p) paper | (b) own labels | (g) own, guarded | (c) east: defaults | "
             "(c) east: tuned on west | (c) west: defaults | (c) west: tuned on east | (d) leave-one-out |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        h = r["halves"]
        loo = pct(r["loo"]["guarded"]) if r["loo"] else "-"
        lines.append(f"| {r['sample']} | {pct(r['default'])} | {pct(r['paper'])} | {pct(r['own'])} | "
                     f"{pct(r['guarded'])} | {pct(h['east']['default'])} | {pct(h['east']['guarded'])} | "
                     f"{pct(h['west']['default'])} | {pct(h['west']['guarded'])} | {loo} |")
    lines.append(f"| **mean** | **{mean([r['default'] for r in rows])}** | **{mean([r['paper'] for r in rows])}** | "
                 f"**{mean([r['own'] for r in rows])}** | **{mean([r['guarded'] for r in rows])}** | "
                 f"{mean([r['halves']['east']['default'] for r in rows])} | "
                 f"{mean([r['halves']['east']['guarded'] for r in rows])} | "
                 f"{mean([r['halves']['west']['default'] for r in rows])} | "
                 f"{mean([r['halves']['west']['guarded'] for r in rows])} | "
                 + (mean([r['loo']['guarded'] for r in rows]) if all(r["loo"] for r in rows) else "-") + " |")
    both_default = [np.mean([r["halves"][k]["default"] for k in ("east", "west")]) for r in rows]
    both_tuned = [np.mean([r["halves"][k]["guarded"] for k in ("east", "west")]) for r in rows]
    worse = [(r["sample"], 100 * (t - d)) for r, d, t in zip(rows, both_default, both_tuned) if t > d]
    kept = sum(r["halves"][k]["kept"] for r in rows for k in ("east", "west"))
    lines += ["", f"(c) both directions (per sample, the mean of its two test halves): guarded {mean(both_tuned)} "
              f"against defaults {mean(both_default)}; the fit was kept in {kept} of {2 * len(rows)} halves; "
              f"better on {sum(t < d for d, t in zip(both_default, both_tuned))} samples, worse on {len(worse)}"
              + (" (" + ", ".join(f"{n} +{x:.2f} pp" for n, x in worse) + ")" if worse else "") + ".",
              "", "(c) unguarded (the best candidate on the training half, always kept): east "
              f"{mean([r['halves']['east']['unguarded'] for r in rows])}, west "
              f"{mean([r['halves']['west']['unguarded'] for r in rows])}.", ""]
    if all(r["loo"] for r in rows):
        lines += [f"(d) kept on {sum(r['loo']['kept'] for r in rows)} of {len(rows)} left-out samples; unguarded "
                  f"(the best candidate on the other 10, always kept): mean {mean([r['loo']['unguarded'] for r in rows])}.",
                  ""]
    lines += [f"(b) chosen values ({', '.join(res['grid'])}): "
              + "; ".join(f"{r['sample']}: {', '.join(f'{v:g}' for v in r['own_choice'].values())}" for r in rows),
              "", "(g) guard on own labels (p-value, kept): "
              + "; ".join(f"{r['sample']}: p={r['guarded_p']:.3g}{' kept' if r['guarded_kept'] else ''}" for r in rows),
              ""]
    if res.get("sweep"):
        lines += ["## The margin of ties", "",
                  "(g) and (c) again with other margins of the rule (total errors within one standard error plus the "
                  "margin of the lowest are ties; the nearest the defaults wins). Worst sample: the largest loss "
                  "against the defaults of a sample's mean over its two test halves; worst half: of one test half.", "",
                  "| margin (points) | (g) own, guarded | (c) both halves, guarded | (c) defaults | worst sample | "
                  "worst half | samples better / worse |", "|---:|---:|---:|---:|---:|---:|---:|"]
        for r in res["sweep"]:
            lines.append(f"| {100 * r['margin']:g} | {pct(r['own_guarded'])} | {pct(r['halves_tuned'])} | "
                         f"{pct(r['halves_default'])} | {100 * r['worst_sample']:+.2f} | {100 * r['worst_half']:+.2f} | "
                         f"{r['better']} / {r['worse']} |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
