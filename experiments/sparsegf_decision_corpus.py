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


def votes(folder: Path) -> dict[str, dict]:
    """Per file: mean votes, SMRF's verdict, reference, scored mask, coordinates (cached in `folder`)."""
    import gfjax
    from gfjax import metrics, sparsegf

    net, config = sparsegf.load_model(None)
    out = {}
    for entry in labelled():
        path = folder / f"{entry.name}.npz"
        if not path.exists():
            cloud = gfjax.read(entry.file)
            d = sparsegf.filter(cloud, model=net, config=config).diagnostics
            np.savez(path, prob=d.prob_ground, smrf=d.smrf_ground, ref=cloud.classification == 2,
                     scored=metrics.scored_mask(cloud.classification), xyz=cloud.xyz_m)
            print(entry.name, flush=True)
        out[entry.name] = dict(np.load(path))
    return out


def decide(d: dict, ground_probability: float, fallback: float | None, despike: bool, level: bool = False) -> np.ndarray:
    from gfjax import spikes
    from gfjax.sparsegf.filter import level_ground_kept

    prob, smrf = d["prob"], d["smrf"]
    used = prob > 0
    rejected = float(np.mean(prob[smrf & used] <= 0.3)) if np.any(smrf & used) else 0.0
    if fallback is not None and rejected > fallback:
        ground = smrf.copy()
    else:
        ground = prob > np.where(smrf, ground_probability, OBJECT_PROBABILITY)
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
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.votes or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        data = votes(folder)
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
              "the points with votes under 0.05 (a test: `tests/test_adaptive.py`). Shipped: "
              "`smrf_ground_probability = 0.05`, level ground kept, then `gfjax.spikes.despike`."]
    out = RESULTS / "sparsegf_decision_corpus.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
