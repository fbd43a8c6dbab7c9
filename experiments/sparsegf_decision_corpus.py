"""SparseGF's decision thresholds and guards on every labelled file: chosen on the training files.

    nice .venv/bin/python experiments/sparsegf_decision_corpus.py [--votes DIR]

The shipped model runs once per file of `experiments.common.LABELLED` (its mean votes and SMRF's
verdict are kept in DIR, a temporary folder by default, so a rerun reuses them). Then each
candidate decision is scored on the same votes: `smrf_ground_probability` (SMRF's ground stays
ground unless the mean vote is at most this; objects need 0.9), a cloud-wide fallback (where
the network rejects more than a share of SMRF's ground, SMRF's labels for the whole cloud),
the spike guard (`gfjax.spikes.despike`) after either, and the level rule
(`gfjax.sparsegf.filter.level_ground_kept`). A file passes with type I <= 10 %
and DTM RMSE <= 0.30 m (`corpus_eval.passes`). The choice is made on the training files only;
the test files' rows are the held-out estimate. Writes
`experiments/results/sparsegf_decision_corpus.md`.

    nice .venv/bin/python experiments/sparsegf_decision_corpus.py --out-of-fold DIR [--votes DIR2]

chooses on votes the network gave files it never trained on: each training file's votes come
from the model of the leave-one-survey-out fold that held its survey out
(`DIR/sparsegf_logo_SURVEY.eqx`, `experiments/sparsegf_logo.py`; every fold must be there), the
validation file's and the test files' from the shipped model. The shipped model's thresholds
were chosen on votes of the files it trained on, which are surer than on a new survey's.
Writes `experiments/results/sparsegf_decision_out_of_fold.md`.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled  # noqa: E402
from experiments.corpus_eval import passes  # noqa: E402

OBJECT_PROBABILITY = 0.9


def votes(folder: Path, models: dict[str, Path] | None = None) -> dict[str, dict]:
    """Per file: mean votes, SMRF's verdict, reference, scored mask, coordinates (cached in
    `folder`); a file of a survey in `models` (survey -> model file) voted by that model, any
    other by the shipped one."""
    import gfjax
    from gfjax import metrics, sparsegf

    models = models or {}
    out = {}
    for entry in labelled():
        model = models.get(entry.survey)
        path = folder / (f"{entry.name}.npz" if model is None else f"{entry.name}.{Path(model).stem}.npz")
        if not path.exists():
            net, config = sparsegf.load_model(model)
            cloud = gfjax.read(entry.file)
            d = sparsegf.filter(cloud, model=net, config=config).diagnostics
            np.savez(path, prob=d.prob_ground, smrf=d.smrf_ground, ref=cloud.classification == 2,
                     scored=metrics.scored_mask(cloud.classification), xyz=cloud.xyz_m)
            print(entry.name, flush=True)
        out[entry.name] = dict(np.load(path))
    return out


def fold_models(folder: Path) -> dict[str, Path]:
    """The leave-one-survey-out model of every survey a training file comes from (but the
    validation file's, which no model trained on), in `folder`; SystemExit naming the missing."""
    from experiments.sparsegf_logo import VALIDATION, surveys

    wanted = {e.survey for e in labelled("train") if e.name != VALIDATION} & set(surveys())
    models = {s: folder / f"sparsegf_logo_{s}.eqx" for s in sorted(wanted)}
    missing = [s for s, path in models.items() if not path.exists()]
    if missing:
        raise SystemExit(f"{folder}: no fold model for {', '.join(missing)} (experiments/sparsegf_logo.py --hold SURVEY)")
    return models


def decide(d: dict, ground_probability: float, fallback: float | None, despike: bool, level: bool = False,
           object_probability: float = OBJECT_PROBABILITY) -> np.ndarray:
    from gfjax import spikes
    from gfjax.sparsegf.filter import level_ground_kept

    prob, smrf = d["prob"], d["smrf"]
    used = prob > 0
    rejected = float(np.mean(prob[smrf & used] <= 0.3)) if np.any(smrf & used) else 0.0
    if fallback is not None and rejected > fallback:
        ground = smrf.copy()
    else:
        ground = prob > np.where(smrf, ground_probability, object_probability)
    if level:
        ground = level_ground_kept(d["xyz"], ground, smrf)
    return spikes.despike(d["xyz"], ground) if despike else ground


def score(d: dict, ground: np.ndarray) -> dict:
    from gfjax import metrics

    p = metrics.point_metrics(ground, d["ref"], mask=d["scored"])
    t = metrics.dtm_metrics(d["xyz"], ground, d["ref"], mask=d["scored"])
    row = {"type1": p["type1"], "total_error": p["total_error"], "rmse_m": t["rmse_m"]}
    row["passes"] = passes(row)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--votes", type=Path, default=None, help="folder of the cached votes (default: a temporary one)")
    parser.add_argument("--out-of-fold", type=Path, default=None, metavar="DIR",
                        help="choose on the votes of the leave-one-survey-out models in DIR")
    args = parser.parse_args()
    models = fold_models(args.out_of_fold) if args.out_of_fold is not None else None
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.votes or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        data = votes(folder, models)
    if models is not None:
        out_of_fold(data)
        return
    candidates = {f"ground vote > {g}": (g, None, False) for g in (0.3, 0.1, 0.05, 0.02)}
    candidates |= {f"fallback over {r:.0%} rejected": (0.3, r, False) for r in (0.1, 0.2, 0.3)}
    candidates |= {"ground vote > 0.05, despiked": (0.05, None, True), "fallback over 20 %, despiked": (0.3, 0.2, True),
                   "ground vote > 0.05, level ground kept, despiked (shipped)": (0.05, None, True, True)}
    entries = labelled()
    lines = ["# SparseGF's decision on every labelled file", "",
             "Command: `nice .venv/bin/python experiments/sparsegf_decision_corpus.py` (the shipped model's votes; "
             "objects need a mean vote > 0.9 throughout). Chosen on the training files: most files passing, then the "
             "lowest mean total error.", "",
             "| decision | train passed | train mean total error % | test passed | test mean type I % | "
             "test ISPRS mean total error % | test failed |", "| --- | ---: | ---: | ---: | ---: | ---: | --- |"]
    for name, (g, r, spike, *level) in candidates.items():
        rows = {e.name: score(data[e.name], decide(data[e.name], g, r, spike, *level)) for e in entries}
        train = [rows[e.name] for e in entries if e.split == "train"]
        test = [(e, rows[e.name]) for e in entries if e.split != "train"]
        isprs = [row["total_error"] for e, row in test if e.survey.startswith("isprs")]
        lines.append(f"| {name} | {sum(x['passes'] for x in train)}/{len(train)} | "
                     f"{100 * np.mean([x['total_error'] for x in train]):.2f} | {sum(x['passes'] for _, x in test)}/{len(test)} | "
                     f"{100 * np.mean([x['type1'] for _, x in test]):.2f} | {100 * np.mean(isprs):.2f} | "
                     f"{', '.join(e.name for e, x in test if not x['passes'])} |")
    lines += ["", "The fallback passes one training file more than the 0.05 threshold alone, but it discards the "
              "network on the forest survey it was trained on (bcts_1's DTM RMSE 0.16 m with the threshold, SMRF's "
              "0.23 m with the fallback), where the network is meant to be best; with the spike guard the threshold "
              "passes as many training files at a lower total error. A rejected point level with the ground kept "
              "around it (within 0.1 m) is given back: on a flat plane of 20 points/m² the network rejects half of "
              "the points with votes under 0.05 (a test: `tests/test_adaptive.py`). Shipped then: "
              "`smrf_ground_probability = 0.05`, level ground kept, then `gfjax.spikes.despike`; since replaced by "
              "0.2, chosen the same way on the votes of models that never saw the file's survey "
              "(`--out-of-fold`, `sparsegf_decision_out_of_fold.md`)."]
    out = RESULTS / "sparsegf_decision_corpus.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def out_of_fold(data: dict[str, dict]) -> None:
    """The shipped decision's two thresholds chosen on out-of-fold votes (the module docstring):
    most training files passing, then the lowest mean total error, then the values nearest the
    shipped ones; level ground kept and despiked as shipped."""
    from gfjax.sparsegf import config as sparsegf_config

    entries = labelled()
    grid = [(g, o) for g in (0.3, 0.2, 0.1, 0.05, 0.02, 0.01) for o in (0.8, 0.9, 0.95, 0.99, 1.0)]
    shipped = (sparsegf_config.SMRF_GROUND_PROBABILITY, sparsegf_config.SMRF_OBJECT_PROBABILITY)
    results = []
    for g, o in grid:
        rows = {e.name: score(data[e.name], decide(data[e.name], g, None, True, True, o)) for e in entries}
        train = [rows[e.name] for e in entries if e.split == "train"]
        results.append(((g, o), rows, sum(x["passes"] for x in train), float(np.mean([x["total_error"] for x in train]))))
    # ties (to 0.01 points of total error) go to the values nearest the shipped ones: a threshold
    # that changes no label is no reason to move
    chosen = max(results, key=lambda r: (r[2], -round(r[3], 4), -abs(r[0][0] - shipped[0]), -abs(r[0][1] - shipped[1])))[0]
    lines = ["# SparseGF's decision chosen on out-of-fold votes", "",
             "Command: `nice .venv/bin/python experiments/sparsegf_decision_corpus.py --out-of-fold DIR`: each training "
             "file voted by the leave-one-survey-out model that never saw its survey (`sparsegf_logo.md`), the "
             "validation and test files by the shipped model. A point SMRF calls ground stays ground when its mean "
             "vote exceeds the first threshold, one SMRF calls an object becomes ground above the second (1.0: never); "
             "level ground kept, then despiked, as shipped. Chosen on the training files: most passing, then the "
             "lowest mean total error (to 0.01 points), then the values nearest the shipped ones. Shipped: "
             f"{shipped[0]} / {shipped[1]}; chosen: **{chosen[0]} / {chosen[1]}**.", "",
             "| SMRF ground kept above / object made ground above | train passed | train mean total error % "
             "| train failed | test passed | test mean type I % | test ISPRS mean total error % | test failed |",
             "| --- | ---: | ---: | --- | ---: | ---: | ---: | --- |"]
    for (g, o), rows, passed, mean in results:
        test = [(e, rows[e.name]) for e in entries if e.split == "test"]
        isprs = [row["total_error"] for e, row in test if e.survey.startswith("isprs")]
        mark = " (chosen)" if (g, o) == chosen else (" (shipped)" if (g, o) == shipped else "")
        failed = ", ".join(e.name for e in entries if e.split == "train" and not rows[e.name]["passes"])
        lines.append(f"| {g} / {o}{mark} | {passed}/{sum(e.split == 'train' for e in entries)} "
                     f"| {100 * mean:.2f} | {failed} | {sum(x['passes'] for _, x in test)}/{len(test)} "
                     f"| {100 * np.mean([x['type1'] for _, x in test]):.2f} | {100 * np.mean(isprs):.2f} "
                     f"| {', '.join(e.name for e, x in test if not x['passes'])} |")
    out = RESULTS / "sparsegf_decision_out_of_fold.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
