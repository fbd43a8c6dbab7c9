"""Each method with and without its low outliers hidden (`gfjax.low_outliers`), on the training files.

    nice .venv/bin/python experiments/low_outliers_methods.py [--methods csf,pmf,...]

Every method runs with its values following the data, as `gfjax.adaptive.run` runs it (the
spike guard after), once without the pre-step and once with it (`hides_low_outliers`), on every
*training* file of `experiments.common.LABELLED` (test files are never read here). Where the
detector flags no point the two runs are one and the same, so that file runs once. A file passes
with type I <= 10 % and DTM RMSE <= 0.30 m (`corpus_eval.passes`). The pre-step ships for a
method (`config.HIDES_LOW_OUTLIERS` of its package) only if it passes no fewer files and its
mean total error is no higher. Writes `experiments/results/low_outliers_methods.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled, write_markdown  # noqa: E402
from experiments.corpus_eval import score_file  # noqa: E402

METHODS = ("csf", "pmf", "dmf", "masf", "smrf")


def run_file(method: str, entry) -> tuple[dict, dict, int]:
    """`(without, with, flagged)`: the scores of both runs on one file and the points hidden."""
    import gfjax
    from gfjax import adaptive, methods

    found = methods.get(method)
    cloud = gfjax.read(entry.file)
    params = found.Params() if found.Params is not None else None
    settled = adaptive.settle_cloud(found.adapt, cloud, found.Config(), params)
    low = adaptive.hide(cloud, settled.terrain)
    flagged = 0 if low is None else int(low.sum())

    def runner(hides: bool):
        return lambda c: adaptive.run(found.filter, c, settled, config=settled.config, params=settled.params,
                                      hides_low_outliers=hides, progress=False).ground

    without = score_file(method, entry, runner(False))
    with_ = score_file(method, entry, runner(True)) if flagged else dict(without)
    return without, with_, flagged


def summary(rows: list[dict]) -> dict:
    isprs = [r for r in rows if r["survey"].startswith("isprs")]
    return {"passed": sum(r["passes"] for r in rows), "files": len(rows),
            "mean_total_error": sum(r["total_error"] for r in rows) / len(rows),
            "isprs_mean_total_error": sum(r["total_error"] for r in isprs) / max(1, len(isprs)),
            "failed": [r["file"] for r in rows if not r["passes"]]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default=",".join(METHODS))
    parser.add_argument("--json", type=Path, default=RESULTS / "low_outliers_methods.json")
    args = parser.parse_args()
    document = json.loads(args.json.read_text()) if args.json.exists() else {}
    for method in args.methods.split(","):
        rows = {"without": [], "with": []}
        for entry in labelled("train"):
            without, with_, flagged = run_file(method, entry)
            rows["without"].append(without)
            rows["with"].append({**with_, "flagged": flagged})
            print(f"{method:5s} {entry.name:12s} hidden {flagged:4d} | TE {100 * without['total_error']:6.2f} "
                  f"T1 {100 * without['type1']:6.2f} RMSE {without['rmse_m']:.3f} -> TE {100 * with_['total_error']:6.2f} "
                  f"T1 {100 * with_['type1']:6.2f} RMSE {with_['rmse_m']:.3f}", flush=True)
        document[method] = {"rows": rows, "summary": {k: summary(v) for k, v in rows.items()}}
        args.json.write_text(json.dumps(document, indent=1))
    lines = ["# Methods with and without their low outliers hidden, on the training files", "",
             "Command: `nice .venv/bin/python experiments/low_outliers_methods.py`. Values following the data and the "
             "spike guard after, as the defaults run (`gfjax.adaptive.run`); *with*: the points of "
             "`gfjax.low_outliers.detect` hidden from the method and labelled non-ground. A file passes with type I "
             "≤ 10 % and DTM RMSE ≤ 0.30 m. ISPRS: the 8 training samples. Test files are not read.", "",
             "| method | passed without | passed with | mean total error % without | with | ISPRS mean total error % "
             "without | with | failed without | failed with |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |"]
    for method in (m for m in METHODS if m in document):
        a, b = document[method]["summary"]["without"], document[method]["summary"]["with"]
        lines.append(f"| {method} | {a['passed']}/{a['files']} | {b['passed']}/{b['files']} | "
                     f"{100 * a['mean_total_error']:.2f} | {100 * b['mean_total_error']:.2f} | "
                     f"{100 * a['isprs_mean_total_error']:.2f} | {100 * b['isprs_mean_total_error']:.2f} | "
                     f"{', '.join(a['failed'])} | {', '.join(b['failed'])} |")
    lines += ["", "Files where points were hidden (total error % / type I % / DTM RMSE m, without -> with):", "",
              "| method | file | hidden | without | with |", "| --- | --- | ---: | --- | --- |"]
    for method in (m for m in METHODS if m in document):
        rows = document[method]["rows"]
        for a, b in zip(rows["without"], rows["with"]):
            if b["flagged"]:
                lines.append(f"| {method} | {a['file']} | {b['flagged']} | {100 * a['total_error']:.2f} / "
                             f"{100 * a['type1']:.2f} / {a['rmse_m']:.3f} | {100 * b['total_error']:.2f} / "
                             f"{100 * b['type1']:.2f} / {b['rmse_m']:.3f} |")
    write_markdown(args.json.with_suffix(".md"), lines)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
