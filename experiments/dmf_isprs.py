"""DMF accuracy: the 11 shared ISPRS reference samples (point labels) and the two BCTS forest
tiles (DTM against the vendor ground), with gfjax SMRF from the same run.

    nice .venv/bin/python experiments/dmf_isprs.py          # writes experiments/results/dmf_isprs.{md,json}

ISPRS: ground = class 2, everything else non-ground; per sample total error, type I, type II,
kappa (SPEC section 8) and the unweighted mean. BCTS: DTM RMSE, mean difference and R_O of
2 m cell-mean DTMs of predicted vs vendor ground, cells valid in both (`metrics.dtm_metrics`);
point figures too, though vendor labels are weak truth there (SPEC section 3, calibration).
Both filters run with their defaults, the same for every file.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import jax
import numpy as np

import gfjax
from gfjax import dmf, metrics
from gfjax.bench.harness import Stopwatch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from experiments.common import DATA as SHARED  # noqa: E402  ($GFJAX_SHARED_DATA; docs/development.md, "Data")

SAMPLES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52", "samp54", "samp71"]
BCTS = ["bcts_1", "bcts_2"]
KEYS = ("total_error", "type1", "type2", "kappa")


def _methods():
    methods = {"dmf": dmf.filter}
    try:
        from gfjax import smrf
        methods["smrf"] = smrf.filter
    except ImportError:
        pass
    return methods


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "dmf_isprs.md")
    args = parser.parse_args(argv)
    jax.config.update("jax_compilation_cache_dir", "/tmp/gfjax_jax_cache")
    methods = _methods()
    rows = {name: {} for name in methods}
    for sample in SAMPLES:
        cloud = gfjax.read(SHARED / "isprs_filtertest" / "reference" / f"{sample}-utm.laz")
        ref = cloud.classification == 2
        for name, run in methods.items():
            with Stopwatch() as watch:                      # the filter and its scoring, as before
                result = run(cloud)
                m = metrics.point_metrics(result.ground, ref)
            rows[name][sample] = {k: m[k] for k in KEYS} | {"seconds": watch.wall_s}
            if name == "dmf":
                d = result.diagnostics
                rows[name][sample] |= {"cell_m": d.cell_m, "basal_iterations": d.basal_iterations,
                                       "instances": int(d.instances.max()), "converged": d.converged}
            print(sample, name, {k: round(v, 4) for k, v in rows[name][sample].items() if isinstance(v, float)}, flush=True)
    forest = {name: {} for name in methods}
    for tile in BCTS:
        cloud = gfjax.read(SHARED / "lasR_bcts" / f"{tile}.laz")
        ref = cloud.classification == 2
        for name, run in methods.items():
            with Stopwatch() as watch:
                result = run(cloud)
            seconds = watch.wall_s
            dtm = metrics.dtm_metrics(cloud.xyz_m, result.ground, ref, cell_m=2.0)
            pm = metrics.point_metrics(result.ground, ref)
            forest[name][tile] = {k: dtm[k] for k in ("rmse_m", "mean_diff_m", "r_o", "r_m", "n_cells_both")} | {
                k: pm[k] for k in KEYS} | {"seconds": seconds}
            print(tile, name, forest[name][tile], flush=True)
    mean = {name: {k: float(np.mean([rows[name][s][k] for s in SAMPLES])) for k in KEYS} for name in methods}
    worst = {name: float(max(rows[name][s]["total_error"] for s in SAMPLES)) for name in methods}
    command = "nice .venv/bin/python experiments/dmf_isprs.py"
    config = dmf.Config()
    params = {k: round(float(getattr(dmf.Params(), k)), 6) for k in ("height_threshold_m", "height_threshold_w")}
    lines = ["# DMF on the ISPRS reference samples and the BCTS tiles\n", f"Command: `{command}`  ",
             f"DMF config (defaults): `{config}`  ",
             f"DMF params (defaults): `{params}` (height threshold = height_threshold_m + height_threshold_w * W)\n",
             "## ISPRS: per-sample total error, type I, type II, kappa (%)\n",
             "| sample | " + " | ".join(f"{n} TE | {n} T1 | {n} T2 | {n} kappa" for n in methods) + " |",
             "|---|" + "---:|" * (4 * len(methods))]
    for s in SAMPLES:
        lines.append(f"| {s} | " + " | ".join(" | ".join(f"{100 * rows[n][s][k]:.2f}" for k in KEYS) for n in methods) + " |")
    lines.append("| **mean** | " + " | ".join(" | ".join(f"**{100 * mean[n][k]:.2f}**" for k in KEYS) for n in methods) + " |")
    lines += ["", "Worst sample total error: " + ", ".join(f"{n} {100 * worst[n]:.2f} %" for n in methods), "",
              "## BCTS forest tiles: DTM (2 m cell means) against the vendor ground\n",
              "| tile | method | RMSE m | mean diff m | R_O % | R_M % | TE % | T1 % | T2 % | seconds |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for tile in BCTS:
        for n in methods:
            f = forest[n][tile]
            lines.append(f"| {tile} | {n} | {f['rmse_m']:.3f} | {f['mean_diff_m']:.3f} | {100 * f['r_o']:.2f} | "
                         f"{100 * f['r_m']:.2f} | {100 * f['total_error']:.2f} | {100 * f['type1']:.2f} | "
                         f"{100 * f['type2']:.2f} | {f['seconds']:.1f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"command": command, "config": str(config), "params": params,
                                                         "isprs": rows, "isprs_mean": mean, "bcts": forest},
                                                        indent=1, default=float))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
