"""Every method on every labelled file we have: point and DTM accuracy against the file's own ground.

    nice .venv/bin/python experiments/corpus_eval.py [--methods smrf,pmf,...] [--jobs 2] [--model M.eqx --json J]

The 29 files of `experiments.common.LABELLED` (11 ISPRS reference samples, bcts_1/2, Topography,
autzen, the 14 vendor-classified tiles of `corpus/`), each method with its defaults. Scored as
`corpus/README.md` says: ground = class 2 against every other class, noise (7, 18), water (9)
and overlap (12) left out (`gfjax.metrics.scored_mask`); total error, type I (ground we call
non-ground), type II; DTM RMSE and omission R_O of cell-mean DTMs on 2 m cells in metres
(`gfjax.metrics.dtm_metrics`); the seconds of the `filter` call (after one warm-up call of the
method on another file; a file of new array shapes may still compile).

A file *passes* when type I <= 10 % and DTM RMSE <= 0.30 m. The summary gives, per method, the
files passed, the means over all files, over the test files (never fitted on:
`split == "test"`) and over the 11 ISPRS samples.

Each method runs in a process of its own (`--jobs` at a time); a rerun of some methods keeps the
others' rows. Writes `experiments/results/corpus_eval.json` and `corpus_eval.md`.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import LABELLED, RESULTS, Labelled, labelled  # noqa: E402
from gfjax.bench.harness import Stopwatch  # noqa: E402
from gfjax.methods import names as method_names  # noqa: E402

METHODS = tuple(method_names())
MAX_TYPE1 = 0.10          # a file passes with type I at most this (fraction) ...
MAX_RMSE_M = 0.30         # ... and a DTM RMSE at most this [m]
CELL_M = 2.0
WARM_UP = "samp24"        # the smallest file: the method's first call, not timed


def passes(row: dict) -> bool:
    """Whether a file's scores meet `MAX_TYPE1` and `MAX_RMSE_M` (a DTM with no common cell fails)."""
    rmse = row["rmse_m"]
    return row["type1"] <= MAX_TYPE1 and not math.isnan(rmse) and rmse <= MAX_RMSE_M


def score_file(method: str, entry: Labelled, run) -> dict:
    """Scores and seconds of `run(cloud) -> ground` on one labelled file."""
    import numpy as np

    import gfjax
    from gfjax import metrics

    cloud = gfjax.read(entry.file)
    with Stopwatch() as watch:
        ground = np.asarray(run(cloud), dtype=bool)
    seconds = watch.wall_s
    reference = cloud.classification == 2
    scored = metrics.scored_mask(cloud.classification)
    point = metrics.point_metrics(ground, reference, mask=scored)
    dtm = metrics.dtm_metrics(cloud.xyz_m, ground, reference, cell_m=CELL_M, mask=scored)
    row = {"file": entry.name, "survey": entry.survey, "split": entry.split, "points": cloud.n_points,
           "seconds": seconds, **{k: point[k] for k in ("total_error", "type1", "type2", "kappa")},
           **{k: dtm[k] for k in ("rmse_m", "r_o", "mean_diff_m")}}
    row["passes"] = passes(row)
    return row


def run_method(method: str, names: list[str], model: str | None = None) -> dict:
    """Every file of `names` with `method`'s defaults, in this process (`model`: the model
    file of a method that takes one; None: the shipped one)."""
    from gfjax import methods

    found = methods.get(method)
    options = {"model": model} if model is not None and found.load_model is not None else {}

    def run(cloud):
        return found.filter(cloud, progress=False, **options).ground

    entries = {e.name: e for e in LABELLED}
    warm = entries[WARM_UP]
    clock = Stopwatch()
    if warm.file.exists():
        score_file(method, warm, run)
    rows = [score_file(method, entries[name], run) for name in names]
    for row in rows:
        print(f"{method:9s} {row['file']:12s} TE {100 * row['total_error']:6.2f} % type I {100 * row['type1']:6.2f} % "
              f"RMSE {row['rmse_m']:.3f} m {row['seconds']:.1f} s", flush=True)
    return {"rows": rows, "warm_up_s": clock.wall_s - sum(r["seconds"] for r in rows)}


def _mean(rows: list[dict], key: str) -> float:
    values = [r[key] for r in rows]
    return sum(values) / len(values) if values else float("nan")


def summarize(rows: list[dict]) -> dict:
    """Per method: files passed and means over all files, the test files and the ISPRS samples."""
    test = [r for r in rows if r["split"] == "test"]
    isprs = [r for r in rows if r["survey"].startswith("isprs")]
    return {
        "files": len(rows), "passed": sum(r["passes"] for r in rows),
        "failed": [r["file"] for r in rows if not r["passes"]],
        **{f"mean_{k}": _mean(rows, k) for k in ("total_error", "type1", "type2", "rmse_m", "r_o")},
        "test_mean_type1": _mean(test, "type1"), "test_mean_rmse_m": _mean(test, "rmse_m"),
        "isprs_mean_total_error": _mean(isprs, "total_error"),
        "seconds": sum(r["seconds"] for r in rows),
    }


def _pct(x: float) -> str:
    return "—" if math.isnan(x) else f"{100 * x:.1f}"


def _m(x: float) -> str:
    return "—" if math.isnan(x) else f"{x:.2f}"


def markdown(document: dict) -> list[str]:
    """The results as a Markdown report."""
    runs = document["methods"]
    names = [m for m in METHODS if m in runs]
    lines = ["# Every method on every labelled file", "",
             "Command: `nice .venv/bin/python experiments/corpus_eval.py` (defaults of every method; "
             f"{document['machine']}). Ground = class 2; classes 7, 9, 12, 18 left out; DTM on {CELL_M:g} m "
             f"cells against the file's own ground. A file passes with type I ≤ {100 * MAX_TYPE1:g} % and DTM "
             f"RMSE ≤ {MAX_RMSE_M:.2f} m. Test files (never fitted on): "
             + ", ".join(e.name for e in LABELLED if e.split == "test") + ".", "",
             "## Summary", "",
             "| method | files passed | mean total error % | mean type I % | mean type II % | mean DTM RMSE m "
             "| mean R_O % | test files: type I % | test files: RMSE m | ISPRS mean total error % | seconds | failed |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    for name in names:
        s = runs[name]["summary"]
        lines.append(f"| {name} | {s['passed']}/{s['files']} | {_pct(s['mean_total_error'])} | {_pct(s['mean_type1'])} "
                     f"| {_pct(s['mean_type2'])} | {_m(s['mean_rmse_m'])} | {_pct(s['mean_r_o'])} "
                     f"| {_pct(s['test_mean_type1'])} | {_m(s['test_mean_rmse_m'])} | {_pct(s['isprs_mean_total_error'])} "
                     f"| {s['seconds']:.0f} | {', '.join(s['failed'])} |")
    lines += ["", "## Per file", "",
              "Total error % / type I % / type II % / DTM RMSE m / R_O % (a failing file in bold).", "",
              "| file | split | points | " + " | ".join(names) + " |",
              "| --- | --- | ---: | " + " | ".join("---" for _ in names) + " |"]
    by_method = {name: {r["file"]: r for r in runs[name]["rows"]} for name in names}
    for entry in LABELLED:
        cells = []
        points = ""
        for name in names:
            row = by_method[name].get(entry.name)
            if row is None:
                cells.append("")
                continue
            points = f"{row['points']:,}"
            text = (f"{_pct(row['total_error'])} / {_pct(row['type1'])} / {_pct(row['type2'])} / "
                    f"{_m(row['rmse_m'])} / {_pct(row['r_o'])}")
            cells.append(text if row["passes"] else f"**{text}**")
        if any(cells):
            lines.append(f"| {entry.name} ({entry.terrain}) | {entry.split} | {points} | " + " | ".join(cells) + " |")
    lines += ["", "Seconds per file (the `filter` call):", "",
              "| file | " + " | ".join(names) + " |", "| --- | " + " | ".join("---:" for _ in names) + " |"]
    for entry in LABELLED:
        cells = [f"{by_method[n][entry.name]['seconds']:.1f}" if entry.name in by_method[n] else "" for n in names]
        if any(cells):
            lines.append(f"| {entry.name} | " + " | ".join(cells) + " |")
    return lines


def _child(method: str, names: list[str], out: Path, model: str | None) -> None:
    out.write_text(json.dumps(run_method(method, names, model)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS), help="comma-separated (default: all)")
    parser.add_argument("--files", default=None, help="comma-separated short names (default: every labelled file)")
    parser.add_argument("--jobs", type=int, default=1, help="methods run at once, each in its own process")
    parser.add_argument("--json", type=Path, default=RESULTS / "corpus_eval.json")
    parser.add_argument("--model", default=None, help="model file of the methods that take one (default: shipped)")
    parser.add_argument("--child", nargs=2, metavar=("METHOD", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    names = [e.name for e in labelled()] if args.files is None else args.files.split(",")
    if args.child:
        _child(args.child[0], names, Path(args.child[1]), args.model)
        return
    chosen = [m for m in args.methods.split(",") if m]
    unknown = sorted(set(chosen) - set(METHODS))
    if unknown:
        parser.error(f"--methods: unknown {', '.join(unknown)}")
    document = json.loads(args.json.read_text()) if args.json.exists() else {"methods": {}}

    def one(method: str) -> tuple[str, dict]:
        out = args.json.with_name(f".corpus_eval-{method}.json")
        command = [sys.executable, __file__, "--child", method, str(out)]
        if args.files:
            command += ["--files", args.files]
        if args.model:
            command += ["--model", args.model]
        subprocess.run(command, check=True)
        result = json.loads(out.read_text())
        out.unlink()
        return method, result

    with ThreadPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        for method, result in pool.map(one, chosen):
            if args.files and method in document["methods"]:      # some files again: keep the others
                kept = [r for r in document["methods"][method]["rows"] if r["file"] not in names]
                result["rows"] = kept + result["rows"]
            order = {e.name: i for i, e in enumerate(LABELLED)}
            result["rows"].sort(key=lambda r: order[r["file"]])
            result["summary"] = summarize(result["rows"])
            document["methods"][method] = result
    document["machine"] = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
                           f"load {os.getloadavg()[0]:.1f} at the end")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(document, indent=1))
    args.json.with_suffix(".md").write_text("\n".join(markdown(document)) + "\n")
    print(f"wrote {args.json} and {args.json.with_suffix('.md')}")


if __name__ == "__main__":
    main()
