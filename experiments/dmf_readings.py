"""Leave-one-out comparison of the DMF readings marked (R) in SPEC section 3.

For every combination of the pipeline readings (basal stop rule, sink cap, hole test) the
filter runs once per ISPRS sample; the step-7 readings (support elevations, final rule and its
threshold) are then applied to the same diagnostics. Leave-one-out: for each of the 11
samples, the reading with the lowest mean total error on the other 10 is chosen and scored on
the held-out sample. An alternative becomes the default only if this LOO score beats the SPEC
default reading on the same 11 samples.

    .venv/bin/python experiments/dmf_readings.py            # writes experiments/results/dmf_readings.{json,md}
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np

import gfjax
from gfjax import dmf, metrics
from gfjax.dmf import extract

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data" / "isprs_filtertest" / "reference").resolve()
SAMPLES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52", "samp54", "samp71"]
# Pipeline readings (each runs the filter once per sample), fixed before this run: the SPEC
# default, the best global-stop reading of a first run of this script (`dmf_readings_run1.md`:
# sink cap 2 W, per-hole test), the best reading of that run (per-node stop, per-hole test), and
# on top of it closing every patch and a majority (not "all") rule for NGNEM_RC. (The shared
# machine allowed no larger grid in the time.)
_KEYS = ("basal_stop", "basal_sink_cap_w", "hole_test", "close_all", "rc_min_share")
PIPELINE = [dict(zip(_KEYS, values)) for values in (
    ("global", None, "patch", False, 1.0), ("global", 2.0, "hole", False, 1.0),
    ("per_node", None, "hole", False, 1.0), ("per_node", None, "hole", True, 1.0),
    ("per_node", None, "hole", False, 0.5), ("per_node", None, "hole", True, 0.5))]
# Step-7 readings on the same diagnostics: the paper's rule, or the height rule with 3
# thresholds. (Support elevations from every ND_CE, "ndce", never reached the top 15 in run 1.)
FINAL = [("m_nearest", "ndng", None)] + [("height", "ndng", t) for t in (0.25, 0.5, 1.0)]
DEFAULT = {"basal_stop": "global", "basal_sink_cap_w": None, "hole_test": "patch", "close_all": False, "rc_min_share": 1.0,
           "support_z": "ndng", "final_rule": "m_nearest", "height_threshold_m": None}


def reading_key(reading: dict) -> str:
    return ",".join(f"{k}={reading[k]}" for k in sorted(reading))


def run_sample(name: str) -> dict[str, dict]:
    cloud = gfjax.read(DATA / f"{name}-utm.laz")
    ref = cloud.classification == 2
    out = {}
    for pipe in PIPELINE:
        config = dmf.Config(**pipe)
        result = dmf.filter(cloud, config=config)
        d = result.diagnostics
        local = cloud.xyz_m - d.origin_m
        for rule, support_z, threshold in FINAL:
            nodes = extract.support_nodes(d.voxels, d.ngnem_rc.reshape(-1), d.in_ndng, v1=config.v1,
                                          fill_neighbours=config.fill_neighbours, support_z=support_z)
            if rule == "m_nearest":
                ground, _ = extract.m_nearest_ground(local, nodes)
            else:
                ground = extract.height_ground(local, nodes, d.voxels, threshold)
            m = metrics.point_metrics(ground, ref)
            reading = dict(pipe, support_z=support_z, final_rule=rule, height_threshold_m=threshold)
            out[reading_key(reading)] = {k: m[k] for k in ("total_error", "type1", "type2", "kappa")}
    return out


def leave_one_out(table: dict[str, dict[str, dict]]) -> dict:
    keys = sorted(next(iter(table.values())))
    te = np.array([[table[s][k]["total_error"] for k in keys] for s in SAMPLES])     # (samples, readings)
    folds = []
    for i, name in enumerate(SAMPLES):
        others = np.delete(te, i, axis=0).mean(axis=0)
        best = int(np.argmin(others))
        folds.append({"held_out": name, "chosen": keys[best], "train_mean_te": float(others[best]),
                      "held_out_te": float(te[i, best])})
    default = reading_key(DEFAULT)
    d = keys.index(default)
    overall = int(np.argmin(te.mean(axis=0)))
    return {"folds": folds, "loo_mean_te": float(np.mean([f["held_out_te"] for f in folds])),
            "default": default, "default_mean_te": float(te[:, d].mean()),
            "best_on_all_11": keys[overall], "best_on_all_11_mean_te": float(te[:, overall].mean()),
            "ranking": [(keys[j], float(te[:, j].mean()), float(te[:, j].max())) for j in np.argsort(te.mean(axis=0))[:15]]}


def main() -> None:
    jax.config.update("jax_compilation_cache_dir", "/tmp/gfjax_jax_cache")      # compiles shared across runs
    out_dir = ROOT / "experiments" / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    table = {}
    for name in SAMPLES:
        t0 = time.perf_counter()
        table[name] = run_sample(name)
        print(f"{name}: {time.perf_counter() - t0:.1f} s", flush=True)
    loo = leave_one_out(table)
    command = "nice -n 2 .venv/bin/python experiments/dmf_readings.py"
    (out_dir / "dmf_readings.json").write_text(json.dumps({"command": command, "loo": loo, "per_sample": table}, indent=1))
    lines = [f"# DMF readings: leave-one-out on the 11 ISPRS samples\n", f"Command: `{command}`\n",
             f"- SPEC default `{loo['default']}`: mean total error {100 * loo['default_mean_te']:.2f} %",
             f"- LOO (choose on 10, score the 11th): mean total error {100 * loo['loo_mean_te']:.2f} %",
             f"- best on all 11: `{loo['best_on_all_11']}`: {100 * loo['best_on_all_11_mean_te']:.2f} %\n",
             "| held out | chosen on the other 10 | train mean TE % | held-out TE % |", "|---|---|---:|---:|"]
    lines += [f"| {f['held_out']} | `{f['chosen']}` | {100 * f['train_mean_te']:.2f} | {100 * f['held_out_te']:.2f} |" for f in loo["folds"]]
    lines += ["", "Top 15 readings by mean total error on all 11 (mean %, worst sample %):", ""]
    lines += [f"- `{k}`: {100 * m:.2f} / {100 * w:.2f}" for k, m, w in loo["ranking"]]
    (out_dir / "dmf_readings.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
