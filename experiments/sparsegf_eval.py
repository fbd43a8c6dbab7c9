"""SparseGF on the test split it never trained on, beside gfjax SMRF's defaults in the same run.

    nice .venv/bin/python experiments/sparsegf_eval.py [--model MODEL.eqx] [--ablation NAME=MODEL.eqx ...]

Test split (SPEC section 5): ISPRS `samp22`, `samp42`, `samp54` (total error, type I/II,
kappa; ground = class 2) and the forest tile `bcts_2` (DTM RMSE and R_O at 2 m cells against
the vendor's ground, whose point labels are weak truth). Each SparseGF model runs with the
settings it was trained with (decision `"network+smrf"` unless stored otherwise; the main
model is scored with the decision `"network"` too); `--ablation` adds a row per extra model (e.g. trained with
`gfjax train --no-refinement`). Times: the warm `filter` call per file (read and write
excluded), points per second over the whole split, and the first call (compiles) apart.
Writes `experiments/results/sparsegf_eval.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

import numpy as np

import gfjax
from gfjax import sparsegf
from gfjax.bench.harness import time_call
from gfjax.metrics import dtm_metrics, point_metrics

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS = DATA / "isprs_filtertest" / "reference"
TEST_SAMPLES = ("samp22", "samp42", "samp54")
FOREST = DATA / "lasR_bcts" / "bcts_2.laz"
RESULTS = ROOT / "experiments" / "results"


def evaluate(name, run, clouds):
    """Scores of one filter `run(cloud) -> ground` on every test cloud."""
    rows = {}
    for label, cloud in clouds.items():
        timing, ground = time_call(lambda: run(cloud), repeat=1, warmup=1)   # the first call, then the warm one
        first_s, again_s = timing.warmup_s[0], timing.times_s[0]
        ref = cloud.classification == 2
        row = {"first_s": first_s, "warm_s": again_s, "points": cloud.n_points}
        if label == "bcts_2":
            row |= dtm_metrics(cloud.xyz_m, ground, ref, cell_m=2.0)
        else:
            row |= point_metrics(ground, ref)
        rows[label] = row
    points = sum(r["points"] for r in rows.values())
    warm = sum(r["warm_s"] for r in rows.values())
    return {"name": name, "files": rows, "points_per_s": points / warm}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None, help="model file (default: the model shipped in gfjax)")
    parser.add_argument("--ablation", nargs="*", default=[], metavar="NAME=MODEL.eqx")
    parser.add_argument("--out", type=Path, default=RESULTS / "sparsegf_eval.md")
    args = parser.parse_args()
    clouds = {s: gfjax.read(ISPRS / f"{s}-utm.laz") for s in TEST_SAMPLES}
    clouds["bcts_2"] = gfjax.read(FOREST)

    runs = [evaluate("gfjax smrf (defaults)", lambda c: gfjax.smrf.filter(c).ground, clouds)]
    models = [("sparsegf " + (Path(args.model).name if args.model else "shipped tiny"), args.model)]
    models += [tuple(item.split("=", 1)) for item in args.ablation]
    for i, (name, path) in enumerate(models):
        net, config = sparsegf.load_model(path)
        decisions = [config] if i else [config, dataclasses.replace(config, decision="network")]
        for config in decisions:            # the main model also alone, without SMRF's verdict
            label = name if config.decision == "network+smrf" else f"{name}, network alone (decision network)"
            runs.append(evaluate(label, lambda c, net=net, config=config: sparsegf.filter(c, model=net, config=config).ground,
                                 clouds))

    lines = ["# SparseGF on the test split (never trained on)", "",
             "Command: `nice .venv/bin/python experiments/sparsegf_eval.py"
             + (f" --model {args.model}" if args.model else "")
             + (" --ablation " + " ".join(args.ablation) if args.ablation else "") + "`  ",
             f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU.", "",
             "| filter | " + " | ".join(f"{s} TE % (I / II, kappa)" for s in TEST_SAMPLES)
             + " | mean TE % | bcts_2 DTM RMSE m | bcts_2 R_O % | points/s (warm filter calls) |",
             "| --- |" + " ---: |" * (len(TEST_SAMPLES) + 4)]
    for run in runs:
        f = run["files"]
        cells = [f"{100 * f[s]['total_error']:.2f} ({100 * f[s]['type1']:.2f} / {100 * f[s]['type2']:.2f}, "
                 f"{f[s]['kappa']:.3f})" for s in TEST_SAMPLES]
        mean = np.mean([100 * f[s]["total_error"] for s in TEST_SAMPLES])
        lines.append(f"| {run['name']} | " + " | ".join(cells) + f" | **{mean:.2f}** | {f['bcts_2']['rmse_m']:.3f} "
                     f"| {100 * f['bcts_2']['r_o']:.2f} | {run['points_per_s']:,.0f} |")
    lines += ["", "Per file, first call (compiles) and warm call [s]: " + "; ".join(
        f"{run['name']}: " + ", ".join(f"{k} {v['first_s']:.1f} / {v['warm_s']:.1f}" for k, v in run["files"].items())
        for run in runs) + "."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(runs, indent=1, default=float))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
