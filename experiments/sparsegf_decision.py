"""SparseGF's decision thresholds, chosen on validation files only.

    nice .venv/bin/python experiments/sparsegf_decision.py [--model MODEL.eqx]

The decision `"network+smrf"` (`gfjax.sparsegf.vote.decide`) labels a point ground when its
mean vote exceeds `r` where SMRF calls it ground and `q` where SMRF calls it an object. This
runs the model once per file with the decision `"network"` (its diagnostics hold the mean
votes and SMRF's verdict), then scores every `(r, q)` of a fixed grid.

The rule, fixed before the run: among the grid points whose DTM on `bcts_1` has R_O <= 5 %
and RMSE <= 0.3 m (the issue's forest bounds), take the lowest total error on the ISPRS
validation file `samp31`; ties go to the `q`, then the `r`, nearest the paper's 0.5.
`samp31` is not trained on; `bcts_1` is (the one labelled forest tile outside the test
split), so its R_O is a biased guide: it is reported beside bcts_2's. The test split (samp22,
samp42, samp54, bcts_2) is scored in the same run for every grid point and plays no part in
the choice. Writes `experiments/results/sparsegf_decision.md` (and `.json`).
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
from gfjax.metrics import dtm_metrics, point_metrics

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS = DATA / "isprs_filtertest" / "reference"
VALIDATION = {"samp31": ISPRS / "samp31-utm.laz", "bcts_1": DATA / "lasR_bcts" / "bcts_1.laz"}
TEST = {s: ISPRS / f"{s}-utm.laz" for s in ("samp22", "samp42", "samp54")} | {"bcts_2": DATA / "lasR_bcts" / "bcts_2.laz"}
GRID_R = (0.1, 0.2, 0.3, 0.4, 0.5)          # threshold where SMRF calls the point ground
GRID_Q = (0.5, 0.6, 0.7, 0.8, 0.9)          # threshold where SMRF calls it an object
R_O_MAX, RMSE_MAX_M = 0.05, 0.3
RESULTS = ROOT / "experiments" / "results"


def scores(files: dict[str, Path], model, config) -> dict:
    """Per file: the mean votes, SMRF's verdict, the reference ground and the coordinates."""
    alone = dataclasses.replace(config, decision="network")
    out = {}
    for name, path in files.items():
        cloud = gfjax.read(path)
        d = sparsegf.filter(cloud, model=model, config=alone).diagnostics
        out[name] = (d.prob_ground, d.smrf_ground, cloud.classification == 2, cloud.xyz_m)
    return out


def evaluate(runs: dict, config) -> dict:
    row = {}
    for name, (prob, smrf_ground, ref, xyz) in runs.items():
        ground = np.asarray(sparsegf.decide(prob, smrf_ground, config=config))
        if name.startswith("bcts"):
            m = dtm_metrics(xyz, ground, ref, cell_m=2.0)
            row[name] = {"r_o": m["r_o"], "rmse_m": m["rmse_m"]}
        else:
            row[name] = {"total_error": point_metrics(ground, ref)["total_error"]}
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None, help="model file (default: the model shipped in gfjax)")
    parser.add_argument("--out", type=Path, default=RESULTS / "sparsegf_decision.md")
    args = parser.parse_args()
    model, trained_with = sparsegf.load_model(args.model)
    runs = scores(VALIDATION | TEST, model, trained_with)

    grid = []
    for r in GRID_R:
        for q in GRID_Q:
            config = dataclasses.replace(trained_with, decision="network+smrf", smrf_ground_probability=r,
                                         smrf_object_probability=q)
            grid.append({"r": r, "q": q} | evaluate(runs, config))
    network = evaluate(runs, dataclasses.replace(trained_with, decision="network"))
    admissible = [g for g in grid if g["bcts_1"]["r_o"] <= R_O_MAX and g["bcts_1"]["rmse_m"] <= RMSE_MAX_M]
    chosen = min(admissible, key=lambda g: (round(g["samp31"]["total_error"], 6), abs(g["q"] - 0.5), abs(g["r"] - 0.5)))

    def cells(g):
        te = [100 * g[s]["total_error"] for s in ("samp22", "samp42", "samp54")]
        return (f"{100 * g['samp31']['total_error']:.2f} | {100 * g['bcts_1']['r_o']:.2f} | {g['bcts_1']['rmse_m']:.3f} | "
                + " | ".join(f"{t:.2f}" for t in te) + f" | {np.mean(te):.2f} | {100 * g['bcts_2']['r_o']:.2f} | "
                f"{g['bcts_2']['rmse_m']:.3f}")

    lines = ["# SparseGF's decision thresholds, chosen on validation", "",
             "Command: `nice .venv/bin/python experiments/sparsegf_decision.py"
             + (f" --model {args.model}" if args.model else "") + "`  ",
             f"Model: {args.model or 'the model shipped in gfjax'} ({trained_with.features}).", "",
             f"Rule (fixed before the run): bcts_1 R_O <= {100 * R_O_MAX:.0f} % and RMSE <= {RMSE_MAX_M} m, then the "
             "lowest samp31 total error; ties to q, then r, nearest 0.5. bcts_1 is a training file. The test "
             "columns were scored in the same run and play no part in the choice.", "",
             f"**Chosen: r = {chosen['r']}, q = {chosen['q']}.**", "",
             "| decision | samp31 TE % | bcts_1 R_O % | bcts_1 RMSE m | samp22 TE % | samp42 TE % | samp54 TE % "
             "| test mean TE % | bcts_2 R_O % | bcts_2 RMSE m |",
             "| --- |" + " ---: |" * 9,
             f"| network alone (mean vote > {trained_with.ground_probability}) | {cells(network)} |"]
    for g in grid:
        mark = " (chosen)" if g is chosen else ""
        lines.append(f"| r = {g['r']}, q = {g['q']}{mark} | {cells(g)} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"chosen": chosen, "network": network, "grid": grid},
                                                        indent=1, default=float))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
