"""Leave-one-out comparison of the DMF readings marked (R) in SPEC section 3, with the forest
DTM criterion.

For every pipeline reading (basal stop rule, sink cap, hole test, closing, NGNEM_RC share) the
filter runs once per file; the step-7 readings (support elevation, final rule, height
threshold) are then applied to the same diagnostics with the functions `extract.extract_ground`
composes. Files: the 11 shared ISPRS samples (point labels) and the two BCTS forest tiles (DTM
of 2 m cell means against the vendor ground; SPEC section 8).

Selection (the forest DTM bound of SPEC section 3): a reading is *forest-feasible* when on both BCTS
tiles its DTM RMSE is at most 0.3 m and R_O at most 5 %. Leave-one-out on ISPRS: for each of
the 11 samples, the forest-feasible reading with the lowest mean total error on the other 10
is chosen and scored on the held-out sample. The unconstrained LOO (ISPRS alone, the previous
selection) is reported next to it. Forest hold-out: feasibility judged on one tile only, the
reading chosen on all 11 ISPRS samples, its DTM reported on the other tile. A reading becomes
the default only if it is the forest-constrained choice on all 11 and its LOO figure beats the
SPEC reading's.

    nice .venv/bin/python experiments/dmf_readings.py       # writes experiments/results/dmf_readings.{json,md}
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import jax
import numpy as np

import gfjax
from gfjax import dmf, metrics
from gfjax.bench.harness import Stopwatch
from gfjax.dmf import extract

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from experiments.common import DATA as SHARED  # noqa: E402  ($GFJAX_SHARED_DATA; docs/development.md, "Data")

SAMPLES = ["samp12", "samp21", "samp22", "samp24", "samp31", "samp41", "samp42", "samp51", "samp52", "samp54", "samp71"]
BCTS = ["bcts_1", "bcts_2"]
FOREST_RMSE_M = 0.3           # DTM RMSE against the vendor ground at most 0.3 m
FOREST_R_O = 0.05             # and R_O at most 5 %, on both tiles
# Pipeline readings (each runs the filter once per file), as in the previous run: the SPEC
# reading, the best global-stop reading of run 1 (`dmf_readings_run1.md`: sink cap 2 W,
# per-hole test), the per-node stop with the per-hole test, and on top of it closing every
# patch and a majority (not "all") rule for NGNEM_RC.
_KEYS = ("basal_stop", "basal_sink_cap_w", "hole_test", "close_all", "rc_min_share")
PIPELINE = [dict(zip(_KEYS, values)) for values in (
    ("global", None, "patch", False, 1.0), ("global", 2.0, "hole", False, 1.0),
    ("per_node", None, "hole", False, 1.0), ("per_node", None, "hole", True, 1.0),
    ("per_node", None, "hole", False, 0.5), ("per_node", None, "hole", True, 0.5))]
# Step-7 readings on the same diagnostics: (final_rule, support_z, support_elevation, threshold
# m, threshold in W). The paper's rule; the height rule with a fixed threshold (the previous
# readings); with a threshold in multiples of W; against the columns' lowest points; both rules
# together; TP_G elevations from every ground column's ND_CE ("ndce") instead of ND_NG only.
FINAL = ([("m_nearest", "ndng", "centroid", None, None)]
         + [("height", "ndng", "centroid", t, 0.0) for t in (0.25, 0.5, 1.0)]
         + [("height", "ndng", "centroid", 0.0, a) for a in (0.1, 0.15, 0.2, 0.25, 0.3)]
         + [("height", "ndng", "lowest", 0.5, 0.0)] + [("height", "ndng", "lowest", 0.0, a) for a in (0.2, 0.3, 0.4)]
         + [("both", "ndng", "centroid", 0.5, 0.0)] + [("both", "ndng", "centroid", 0.0, a) for a in (0.15, 0.3)]
         + [("m_nearest", "ndce", "centroid", None, None), ("height", "ndce", "centroid", 0.0, 0.15)])
SPEC_READING = {"basal_stop": "global", "basal_sink_cap_w": None, "hole_test": "patch", "close_all": False,
                "rc_min_share": 1.0, "final_rule": "m_nearest", "support_z": "ndng", "support_elevation": "centroid",
                "height_threshold_m": None, "height_threshold_w": None}
PREVIOUS_DEFAULT = {"basal_stop": "per_node", "basal_sink_cap_w": None, "hole_test": "hole", "close_all": True,
                    "rc_min_share": 1.0, "final_rule": "height", "support_z": "ndng", "support_elevation": "centroid",
                    "height_threshold_m": 0.5, "height_threshold_w": 0.0}
_STEP7 = ("final_rule", "support_z", "support_elevation", "height_threshold_m", "height_threshold_w")
POINT_KEYS = ("total_error", "type1", "type2", "kappa")
DTM_KEYS = ("rmse_m", "mean_diff_m", "r_o", "r_m")


def reading_key(reading: dict) -> str:
    return ",".join(f"{k}={reading[k]}" for k in sorted(reading))


def _read(name: str) -> gfjax.Cloud:
    if name.startswith("bcts"):
        return gfjax.read(SHARED / "lasR_bcts" / f"{name}.laz")
    return gfjax.read(SHARED / "isprs_filtertest" / "reference" / f"{name}-utm.laz")


def _score(name: str, cloud: gfjax.Cloud, ground: np.ndarray) -> dict:
    ref = cloud.classification == 2
    m = metrics.point_metrics(ground, ref)
    out = {k: m[k] for k in POINT_KEYS}
    if name.startswith("bcts"):
        dtm = metrics.dtm_metrics(cloud.xyz_m, ground, ref, cell_m=2.0)
        out |= {k: dtm[k] for k in DTM_KEYS}
    return out


def _params_defaults() -> dict:
    return {k: float(getattr(dmf.Params(), k)) for k in ("height_threshold_m", "height_threshold_w")}


def _is_default_step7(rule, support_z, elevation, t_m, t_w) -> bool:
    config, params = dmf.Config(), _params_defaults()
    step7 = (config.final_rule, config.support_z, config.support_elevation)
    return ((rule, support_z, elevation) == step7 and t_m is not None
            and np.isclose(t_m, params["height_threshold_m"]) and np.isclose(t_w, params["height_threshold_w"]))


def run_file(name: str) -> dict[str, dict]:
    """Every (pipeline, step-7) reading on one file: `{reading key: scores}`."""
    cloud = _read(name)
    use = cloud.filter_mask("all")
    out = {}
    for pipe in PIPELINE:
        config = dmf.Config(**pipe)
        result = dmf.filter(cloud, config=config)
        d = result.diagnostics
        local = cloud.xyz_m[use] - d.origin_m
        object_cell = d.ngnem_rc.reshape(-1)
        nodes, nearest = {}, {}
        for rule, support_z, elevation, t_m, t_w in FINAL:
            surface = (support_z, elevation)
            if surface not in nodes:
                own = extract.column_lowest(local, d.voxels) if elevation == "lowest" else None
                nodes[surface] = extract.support_nodes(d.voxels, object_cell, d.in_ndng, v1=config.v1,
                                                       fill_neighbours=config.fill_neighbours, support_z=support_z,
                                                       support_position=config.support_position, own=own)
            ground = np.ones(len(local), bool)
            if rule in ("m_nearest", "both"):
                if surface not in nearest:
                    nearest[surface] = extract.m_nearest_ground(local, nodes[surface])[0]
                ground = nearest[surface]
            if rule in ("height", "both"):
                params = dmf.Params(height_threshold_m=t_m, height_threshold_w=t_w)
                ground = ground & extract.height_ground(local, nodes[surface], d.voxels, params.threshold_m(d.cell_m))
            ground_all = np.zeros(cloud.n_points, bool)
            ground_all[use] = ground
            if _is_default_step7(rule, support_z, elevation, t_m, t_w):       # same answer as the filter itself
                assert np.array_equal(ground_all, result.ground), (name, pipe)
            reading = dict(pipe, final_rule=rule, support_z=support_z, support_elevation=elevation,
                           height_threshold_m=t_m, height_threshold_w=t_w)
            out[reading_key(reading)] = _score(name, cloud, ground_all) | {"cell_m": d.cell_m}
    return out


def _feasible(table: dict, keys: list[str], tiles: list[str]) -> np.ndarray:
    return np.array([all(table[t][k]["rmse_m"] <= FOREST_RMSE_M and table[t][k]["r_o"] <= FOREST_R_O for t in tiles)
                     for k in keys])


def _loo(te: np.ndarray, keys: list[str], allowed: np.ndarray) -> dict:
    folds = []
    for i, name in enumerate(SAMPLES):
        others = np.where(allowed, np.delete(te, i, axis=0).mean(axis=0), np.inf)
        best = int(np.argmin(others))
        folds.append({"held_out": name, "chosen": keys[best], "train_mean_te": float(others[best]),
                      "held_out_te": float(te[i, best])})
    overall = int(np.argmin(np.where(allowed, te.mean(axis=0), np.inf)))
    return {"folds": folds, "loo_mean_te": float(np.mean([f["held_out_te"] for f in folds])),
            "chosen_on_all_11": keys[overall], "chosen_mean_te": float(te[:, overall].mean()),
            "chosen_worst_te": float(te[:, overall].max())}


def select(table: dict[str, dict[str, dict]]) -> dict:
    keys = sorted(table[SAMPLES[0]])
    te = np.array([[table[s][k]["total_error"] for k in keys] for s in SAMPLES])     # (samples, readings)
    feasible = _feasible(table, keys, BCTS)
    forest_holdout = []
    for i, tile in enumerate(BCTS):
        other = BCTS[1 - i]
        chosen = keys[int(np.argmin(np.where(_feasible(table, keys, [other]), te.mean(axis=0), np.inf)))]
        forest_holdout.append({"judged_on": other, "held_out": tile, "chosen": chosen,
                               **{k: table[tile][chosen][k] for k in ("rmse_m", "mean_diff_m", "r_o")}})
    order = np.argsort(te.mean(axis=0))

    def row(k):
        j = keys.index(k)
        return {"reading": k, "mean_te": float(te[:, j].mean()), "worst_te": float(te[:, j].max()),
                **{f"{t}_{m}": table[t][k][m] for t in BCTS for m in ("rmse_m", "mean_diff_m", "r_o")},
                "forest_feasible": bool(feasible[j])}

    by_step7 = {}                        # the best pipeline for each step-7 reading
    for j in order:
        step7 = tuple(part for part in keys[j].split(",") if part.split("=")[0] in _STEP7)
        by_step7.setdefault(step7, row(keys[j]))
    return {"n_readings": len(keys), "n_forest_feasible": int(feasible.sum()), "by_step7": list(by_step7.values()),
            "constrained": _loo(te, keys, feasible), "isprs_only": _loo(te, keys, np.ones(len(keys), bool)),
            "forest_holdout": forest_holdout,
            "spec": row(reading_key(SPEC_READING)), "previous_default": row(reading_key(PREVIOUS_DEFAULT)),
            "ranking": [row(keys[j]) for j in order[:20]],
            "ranking_feasible": [row(keys[j]) for j in order if feasible[j]][:15]}


def _row_md(r: dict) -> str:
    forest = " | ".join(f"{r[f'{t}_rmse_m']:.3f} | {r[f'{t}_mean_diff_m']:+.3f} | {100 * r[f'{t}_r_o']:.2f}"
                        for t in BCTS)
    ok = "yes" if r["forest_feasible"] else "no"
    return f"| `{r['reading']}` | {100 * r['mean_te']:.2f} | {100 * r['worst_te']:.2f} | {forest} | {ok} |"


def report(sel: dict, command: str, seconds: float) -> list[str]:
    c, u = sel["constrained"], sel["isprs_only"]
    head = ("| reading | ISPRS mean TE % | worst % | bcts_1 RMSE m | bcts_1 mean diff m | bcts_1 R_O % | "
            "bcts_2 RMSE m | bcts_2 mean diff m | bcts_2 R_O % | forest ok |")
    sep = "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"
    lines = ["# DMF readings: leave-one-out on the 11 ISPRS samples, with the forest DTM criterion\n",
             f"Command: `{command}` ({seconds / 60:.1f} min)  ",
             f"{sel['n_readings']} readings ({len(PIPELINE)} pipelines x {len(FINAL)} step-7 readings); "
             f"{sel['n_forest_feasible']} are forest-feasible (both BCTS tiles: DTM RMSE <= {FOREST_RMSE_M} m, "
             f"R_O <= {100 * FOREST_R_O:.0f} %).\n",
             "## Summary\n", head, sep, _row_md(sel["spec"]) + " SPEC reading",
             _row_md(sel["previous_default"]) + " previous default",
             "",
             "- LOO among forest-feasible readings (choose on 10, score the 11th): mean total error "
             f"**{100 * c['loo_mean_te']:.2f} %**",
             f"- chosen on all 11 among forest-feasible readings: `{c['chosen_on_all_11']}`: "
             f"{100 * c['chosen_mean_te']:.2f} % (worst sample {100 * c['chosen_worst_te']:.2f} %)",
             f"- LOO on ISPRS alone (the previous selection, forest ignored): {100 * u['loo_mean_te']:.2f} %; "
             f"chosen on all 11: `{u['chosen_on_all_11']}`: {100 * u['chosen_mean_te']:.2f} %",
             "- forest hold-out (feasible on one tile, chosen on ISPRS, scored on the other tile): "
             + "; ".join(f"judged on {f['judged_on']} -> `{f['chosen']}`: {f['held_out']} RMSE {f['rmse_m']:.3f} m, "
                         f"mean diff {f['mean_diff_m']:+.3f} m, R_O {100 * f['r_o']:.2f} %" for f in sel["forest_holdout"]),
             "", "## Forest-constrained leave-one-out folds\n",
             "| held out | chosen on the other 10 | train mean TE % | held-out TE % |", "|---|---|---:|---:|"]
    lines += [f"| {f['held_out']} | `{f['chosen']}` | {100 * f['train_mean_te']:.2f} | {100 * f['held_out_te']:.2f} |"
              for f in c["folds"]]
    lines += ["", "## Each step-7 reading with its best pipeline reading (by ISPRS mean total error)\n", head, sep]
    lines += [_row_md(r) for r in sel["by_step7"]]
    lines += ["", "## Top 15 forest-feasible readings by ISPRS mean total error\n", head, sep]
    lines += [_row_md(r) for r in sel["ranking_feasible"]]
    lines += ["", "## Top 20 readings by ISPRS mean total error (forest ignored)\n", head, sep]
    lines += [_row_md(r) for r in sel["ranking"]]
    return lines


def main() -> None:
    jax.config.update("jax_compilation_cache_dir", "/tmp/gfjax_jax_cache")      # compiles shared across runs
    out_dir = ROOT / "experiments" / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    clock = Stopwatch()
    table = {}
    for name in SAMPLES + BCTS:
        with Stopwatch() as watch:
            table[name] = run_file(name)
        print(f"{name}: {watch.wall_s:.1f} s", flush=True)
    sel = select(table)
    command = "nice .venv/bin/python experiments/dmf_readings.py"
    seconds = clock.wall_s
    (out_dir / "dmf_readings.json").write_text(json.dumps(
        {"command": command, "config_defaults": str(dmf.Config()), "params_defaults": _params_defaults(),
         "selection": sel, "per_file": table}, indent=1, default=float))
    lines = report(sel, command, seconds)
    (out_dir / "dmf_readings.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
