"""Candidate rules for a method's data-following defaults, scored on the training files only.

    nice .venv/bin/python experiments/adaptive_rules.py METHOD [--candidates NAME,...]

Each candidate is a function of the cloud's `gfjax.adaptive.Terrain` giving values for some of
the method's `Config` / `Params` fields (the rest stay the fixed defaults). Every candidate runs
on every *training* file of `experiments.common.LABELLED` (test files are never read here);
a file passes with type I <= 10 % and DTM RMSE <= 0.30 m, as in `corpus_eval.py`. The choice
is made by leave-one-survey-out: for each survey, the candidate that passes the most files of
the other surveys (ties: the lower mean total error) is scored on the held-out survey; the
summed held-out passes estimate how the rule-picking carries to a survey it did not see. The
candidate chosen on all training surveys is what ships (`gfjax.<method>.adapt`).
Writes `experiments/results/adaptive_rules_<method>.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled  # noqa: E402
from experiments.corpus_eval import score_file  # noqa: E402

Rule = Callable[..., dict]


def _half_floor(x: float) -> float:
    return math.floor(x / 0.5) * 0.5


def _smrf_cell(t) -> float:
    from gfjax import smrf

    return smrf.adapt(t)["cell_m"]


def _coarse_cell(t) -> dict:
    """`cell_m` where the spacing rule coarsens it (sparse last returns), nothing elsewhere, so
    a candidate with it shares its runs on every other file."""
    from gfjax import adaptive

    cell = adaptive.raster_cell_m(t)
    return {} if cell == 1.0 else {"cell_m": cell}


def _csf_adapt(t) -> dict:
    from gfjax import csf

    return csf.adapt(t)


# Candidates per method: name -> terrain -> field values. "fixed" is the method's fixed defaults.
CANDIDATES: dict[str, dict[str, Rule]] = {
    "pmf": {
        "fixed": lambda t: {},
        "cell": lambda t: {"cell_m": _smrf_cell(t)},
        "dh0 0.3": lambda t: {"initial_distance_m": 0.3},
        "dh0 0.5": lambda t: {"initial_distance_m": 0.5},
        "slope p90": lambda t: {"slope": max(1.0, 2 * t.slope_p90)},
        "dhmax relief": lambda t: {"max_distance_m": max(2.5, t.slope_p90 * 33.0 / 2)},
        "cell+dh0 0.3+dhmax": lambda t: {"cell_m": _smrf_cell(t), "initial_distance_m": 0.3,
                                         "max_distance_m": max(2.5, t.slope_p90 * 33.0 / 2)},
        "cell+dh0 0.5+dhmax": lambda t: {"cell_m": _smrf_cell(t), "initial_distance_m": 0.5,
                                         "max_distance_m": max(2.5, t.slope_p90 * 33.0 / 2)},
        "cell+dh0 0.3+dhmax+slope": lambda t: {"cell_m": _smrf_cell(t), "initial_distance_m": 0.3,
                                               "max_distance_m": max(2.5, t.slope_p90 * 33.0 / 2),
                                               "slope": max(1.0, 2 * t.slope_p90)},
        "dh0 0.5+dhmax p50": lambda t: {"initial_distance_m": 0.5, "max_distance_m": max(2.5, t.slope_p50 * 33.0 / 2)},
        "dh0 0.5+dhmax p50+cell": lambda t: {"cell_m": _smrf_cell(t), "initial_distance_m": 0.5,
                                             "max_distance_m": max(2.5, t.slope_p50 * 33.0 / 2)},
        "dh0 0.5+slope p50": lambda t: {"initial_distance_m": 0.5, "slope": max(1.0, 4 * t.slope_p50)},
    },
    "smrf": {
        "cell": lambda t: {"cell_m": _smrf_cell(t)},
        "cell+slope p90": lambda t: {"cell_m": _smrf_cell(t), "slope": round(max(0.15, t.slope_p90), 3)},
        "cell+slope p90/2": lambda t: {"cell_m": _smrf_cell(t), "slope": round(max(0.15, t.slope_p90 / 2), 3)},
        "cell+slope 2 p50": lambda t: {"cell_m": _smrf_cell(t), "slope": round(max(0.15, 2 * t.slope_p50), 3)},
        "cell+slope 0.1+p90/2": lambda t: {"cell_m": _smrf_cell(t), "slope": round(0.1 + t.slope_p90 / 2, 3)},
        "cell+slope 0.2": lambda t: {"cell_m": _smrf_cell(t), "slope": 0.2},
        "cell+slope 0.1": lambda t: {"cell_m": _smrf_cell(t), "slope": 0.1},
    },
    "csf": {
        "fixed": lambda t: {},
        "trend 30": lambda t: {"trend_m": 30.0},
        "trend 30+rigid 1": lambda t: {"trend_m": 30.0, "rigidness": 1},
        "trend 30+rigid by slope": lambda t: {"trend_m": 30.0,
                                              "rigidness": 3 if t.slope_p90 < 0.15 else (2 if t.slope_p90 < 0.4 else 1)},
        "rigid by slope": lambda t: {"rigidness": 3 if t.slope_p90 < 0.15 else (2 if t.slope_p90 < 0.4 else 1)},
        "trend 30+rigid 1+cell": lambda t: {"trend_m": 30.0, "rigidness": 1, **_coarse_cell(t)},
        "trend 30+rigid 1+thr slope": lambda t: {"trend_m": 30.0, "rigidness": 1,
                                                 "class_threshold_m": round(0.5 + 2 * t.slope_p90, 3)},
        "trend 30+rigid 1+thr slope x4": lambda t: {"trend_m": 30.0, "rigidness": 1,
                                                    "class_threshold_m": round(0.5 + 4 * t.slope_p90, 3)},
        "trend 30+rigid 1+thr slope<=1": lambda t: {"trend_m": 30.0, "rigidness": 1,
                                                    "class_threshold_m": round(min(1.0, 0.5 + 2 * t.slope_p90), 3)},
        "trend 30+rigid 1+dt 1": lambda t: {"trend_m": 30.0, "rigidness": 1, "time_step": 1.0},
        "trend 30+rigid 1+dt 0.8": lambda t: {"trend_m": 30.0, "rigidness": 1, "time_step": 0.8},
        "trend 30+rigid 1+dt 1 on relief": lambda t: {"trend_m": 30.0, "rigidness": 1,
                                                      **({"time_step": 1.0} if t.slope_p90 >= 0.15 else {})},
        "trend 30+rigid 1+dt 1 on relief+thr slope<=1": lambda t: {
            "trend_m": 30.0, "rigidness": 1, "class_threshold_m": round(min(1.0, 0.5 + 2 * t.slope_p90), 3),
            **({"time_step": 1.0} if t.slope_p90 >= 0.15 else {})},
        "trend 30+rigid 1+dt 1 on relief 0.2+thr slope<=1": lambda t: {
            "trend_m": 30.0, "rigidness": 1, "class_threshold_m": round(min(1.0, 0.5 + 2 * t.slope_p90), 3),
            **({"time_step": 1.0} if t.slope_p90 >= 0.2 else {})},
        "trend 30+rigid 1+dt 1 on relief 0.2+thr slope<=1.25": lambda t: {
            "trend_m": 30.0, "rigidness": 1, "class_threshold_m": round(min(1.25, 0.5 + 2 * t.slope_p90), 3),
            **({"time_step": 1.0} if t.slope_p90 >= 0.2 else {})},
        "shipped: ... +thr slope<=1.25+trend of four last returns a cell": lambda t: _csf_adapt(t),
        "trend 30+rigid 1+dt 1.2 on relief 0.2+thr slope<=1": lambda t: {
            "trend_m": 30.0, "rigidness": 1, "class_threshold_m": round(min(1.0, 0.5 + 2 * t.slope_p90), 3),
            **({"time_step": 1.2} if t.slope_p90 >= 0.2 else {})},
    },
    "masf": {
        # Every value spelled out: the candidates replace `masf.adapt`, and "before" is the
        # defaults before the buffer heights, the mirror test and alpha_max 25 m.
        "before": lambda t: {"alpha_max_m": 20.0, "buffer_heights": "top", "mirror_max_m": None},
        "no neighbour test": lambda t: {"neighbour_test": False, "alpha_max_m": 20.0, "mirror_max_m": None},
        "alpha 25": lambda t: {"neighbour_test": False, "alpha_max_m": 25.0, "mirror_max_m": None},
        "alpha 30": lambda t: {"neighbour_test": False, "alpha_max_m": 30.0, "mirror_max_m": None},
        "alpha 30 + mirror 1": lambda t: {"neighbour_test": False, "alpha_max_m": 30.0, "mirror_max_m": 1.0},
        "alpha 30 + mirror 1.5": lambda t: {"neighbour_test": False, "alpha_max_m": 30.0, "mirror_max_m": 1.5},
        "alpha 25 + mirror 1.5": lambda t: {"neighbour_test": False, "alpha_max_m": 25.0, "mirror_max_m": 1.5},
    },
    "dmf": {
        "fixed": lambda t: {},
        "threshold +0.5 p90": lambda t: {"height_threshold_w": round(0.2 + 0.5 * t.slope_p90, 3)},
        "threshold +1 p90": lambda t: {"height_threshold_w": round(0.2 + 1.0 * t.slope_p90, 3)},
    },
}


def run_candidate(method: str, make: Rule, entry, cache: dict) -> dict:
    """Scores of one candidate on one file (runs shared between candidates giving the same values)."""
    import gfjax
    from gfjax import adaptive, methods

    module = methods.get(method)
    cloud = gfjax.read(entry.file)
    terrain = adaptive.settle_cloud(lambda t: {}, cloud, module.Config(), None).terrain
    values = make(terrain)
    key = (entry.name, tuple(sorted(values.items())))
    if key not in cache:
        settled = adaptive.settle_terrain(lambda t: values, terrain, module.Config(),
                                          module.Params() if getattr(module, "Params", None) else None)
        row = score_file(method, entry, lambda c: adaptive.run(
            module.filter, c, settled, config=settled.config, params=settled.params,
            hides_low_outliers=module.hides_low_outliers, progress=False).ground)
        cache[key] = {**row, "values": {k: (v if not isinstance(v, float) else round(v, 4)) for k, v in values.items()}}
    return cache[key]


def choose(rows_by_candidate: dict[str, list[dict]], surveys: set[str]) -> str:
    """The candidate passing the most files of `surveys` (ties: the lowest mean total error)."""
    def key(name: str):
        rows = [r for r in rows_by_candidate[name] if r["survey"] in surveys]
        return (-sum(r["passes"] for r in rows), sum(r["total_error"] for r in rows) / max(1, len(rows)))
    return min(rows_by_candidate, key=key)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("method", choices=sorted(CANDIDATES))
    parser.add_argument("--candidates", default=None, help="comma-separated names (default: all of the method's)")
    parser.add_argument("--files", default=None, help="comma-separated training files (default: all; a trial, "
                                                      "the results file says which)")
    args = parser.parse_args()
    candidates = CANDIDATES[args.method]
    if args.candidates:
        candidates = {k: candidates[k] for k in args.candidates.split(",")}
    train = labelled("train")
    if args.files:
        train = [e for e in train if e.name in args.files.split(",")]
    cache: dict = {}
    rows = {name: [] for name in candidates}
    for entry in train:
        for name, make in candidates.items():
            row = run_candidate(args.method, make, entry, cache)
            rows[name].append(row)
            print(f"{args.method} {name:28s} {entry.name:12s} TE {100 * row['total_error']:6.2f} T1 {100 * row['type1']:6.2f} "
                  f"RMSE {row['rmse_m']:.3f} {'' if row['passes'] else 'FAIL'}", flush=True)
    surveys = sorted({e.survey for e in train})
    held_out = []
    for survey in surveys:
        pick = choose(rows, set(surveys) - {survey})
        held_out += [dict(r, chosen=pick) for r in rows[pick] if r["survey"] == survey]
    chosen = choose(rows, set(surveys))
    summary = {name: {"passed": sum(r["passes"] for r in rs), "files": len(rs),
                      "mean_total_error": sum(r["total_error"] for r in rs) / len(rs),
                      "mean_type1": sum(r["type1"] for r in rs) / len(rs),
                      "mean_type2": sum(r["type2"] for r in rs) / len(rs),
                      "failed": [r["file"] for r in rs if not r["passes"]]} for name, rs in rows.items()}
    loso = {"passed": sum(r["passes"] for r in held_out), "files": len(held_out),
            "mean_total_error": sum(r["total_error"] for r in held_out) / len(held_out),
            "picks": {s: next(r["chosen"] for r in held_out if r["survey"] == s) for s in surveys
                      if any(r["survey"] == s for r in held_out)}}
    out = RESULTS / f"adaptive_rules_{args.method}.json"
    out.write_text(json.dumps({"chosen": chosen, "summary": summary, "leave_one_survey_out": loso,
                               "rows": rows}, indent=1, default=str))
    lines = [f"# {args.method}: candidate rules on the training files", "",
             f"Command: `nice .venv/bin/python experiments/adaptive_rules.py {args.method}`. "
             f"{len(train)} training files of {len(surveys)} surveys; a file passes with type I ≤ 10 % and "
             "DTM RMSE ≤ 0.30 m. Test files are not read. Every candidate runs as the defaults do: low outliers "
             "hidden first where the method hides them, the guard of `gfjax.spikes` after." + (f" Trial on {len(train)} files only." if args.files else ""), "",
             "| candidate | passed | mean total error % | mean type I % | mean type II % | failed |",
             "| --- | ---: | ---: | ---: | ---: | --- |"]
    for name, s in summary.items():
        mark = " (chosen)" if name == chosen else ""
        lines.append(f"| {name}{mark} | {s['passed']}/{s['files']} | {100 * s['mean_total_error']:.2f} | "
                     f"{100 * s['mean_type1']:.2f} | {100 * s['mean_type2']:.2f} | {', '.join(s['failed'])} |")
    lines += ["", f"Leave one survey out (choose on the other surveys, score the held-out one): "
              f"{loso['passed']}/{loso['files']} files pass, mean total error {100 * loso['mean_total_error']:.2f} %; "
              "picks: " + ", ".join(f"{s}: {p}" for s, p in loso["picks"].items()) + "."]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
