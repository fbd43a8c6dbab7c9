"""Can the points SMRF, MASF and PMF disagree on be labelled better than by their majority?

    nice .venv/bin/python experiments/vote_disagreements.py --labels /tmp/vote_labels

On the 11 ISPRS samples (the voters' labels cached as `vote_select.py` caches them), the
points are split by the voters' pattern (which of the three call a point ground), and each
pattern's ground and non-ground points are counted. Then rules that relabel the points the
voters disagree on (one or two of three say ground), the agreed points keeping their label:

- the hindsight bound: each disagreement pattern given the label that errs less on all 11
  samples (the test samples included: a ceiling, not a rule);
- the height above a TIN of the points all three call ground, `abs(h) < t` and `h < t`;
- the share of ground votes among a point's 8 nearest neighbours (in x, y) averaged with its own,
  `> t`;
- a logistic model of the three votes, that share, `h` and `abs(h)`, fitted on the disagreement
  points of the ISPRS training samples of the other surveys (leave one survey out);
- and, on every point, the ground-spike guard (`gfjax.spikes.guard`) run once more on the
  vote's labels (each voter's already ran through it).

A rule's threshold is the one with the lowest mean total error on the 8 training samples among
those listed (`THRESHOLDS`); each row reports all 11 samples.
Writes `experiments/results/vote_disagreements.md`.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled, write_markdown  # noqa: E402
from experiments.vote_select import labels  # noqa: E402

VOTERS = ("smrf", "masf", "pmf")
NEIGHBOURS = 8
THRESHOLDS = {"abs(h) < t": (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 3.0), "h < t": (0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 3.0),
              "neighbour share > t": (0.4, 0.5, 0.55, 0.6, 0.65)}


def sample(entry, folder: Path) -> dict:
    """One sample's votes `(3, n)`, reference, scored mask, height above the unanimous TIN `(n,)`
    [m] and neighbour share `(n,)`."""
    from scipy.interpolate import LinearNDInterpolator, NearestNDInterpolator
    from scipy.spatial import cKDTree

    import gfjax
    from gfjax import metrics

    cloud = gfjax.read(entry.file)
    votes = np.stack([labels(m, entry, folder) for m in VOTERS])
    count = votes.sum(axis=0)
    from gfjax import adaptive, spikes

    terrain = adaptive.measure_cloud(cloud)
    guarded = spikes.guard(cloud.xyz_m, cloud.filter_mask("all"), count >= 2, spacing_m=terrain.spacing_m,
                           slope_p90=terrain.slope_p90)
    xy, z = cloud.xyz_m[:, :2], cloud.xyz_m[:, 2]
    agreed = count == 3
    surface = LinearNDInterpolator(xy[agreed], z[agreed])(xy)
    outside = np.isnan(surface)
    surface[outside] = NearestNDInterpolator(xy[agreed], z[agreed])(xy[outside])
    _, near = cKDTree(xy).query(xy, k=NEIGHBOURS + 1)
    share = 0.5 * (count / 3 + count[near[:, 1:]].mean(axis=1) / 3)
    return {"votes": votes, "count": count, "reference": cloud.classification == 2,
            "scored": metrics.scored_mask(cloud.classification), "h": z - surface, "share": share,
            "guarded": guarded,
            "survey": entry.survey, "split": entry.split}


def total_error(ground: np.ndarray, s: dict) -> float:
    return 100 * float(((ground != s["reference"]) & s["scored"]).sum() / s["scored"].sum())


def relabel(s: dict, disputed_ground: np.ndarray) -> np.ndarray:
    """The majority where the voters agree, `disputed_ground` where they do not."""
    disputed = (s["count"] == 1) | (s["count"] == 2)
    return np.where(disputed, disputed_ground, s["count"] >= 2)


def features(s: dict) -> np.ndarray:
    h = np.clip(s["h"], -3.0, 3.0)
    return np.column_stack([s["votes"].T.astype(float), s["share"], h, np.abs(h), np.ones(len(h))])


def fit_logistic(samples: list[dict]) -> np.ndarray:
    """Weights of a logistic model of `features` on the disputed points of `samples`, each
    sample weighing as much as the others (its points by 1 / its scored points)."""
    from scipy.optimize import minimize

    x, y, w = [], [], []
    for s in samples:
        disputed = ((s["count"] == 1) | (s["count"] == 2)) & s["scored"]
        x.append(features(s)[disputed])
        y.append(s["reference"][disputed])
        w.append(np.full(disputed.sum(), 1.0 / s["scored"].sum()))
    x, y, w = np.vstack(x), np.concatenate(y).astype(float), np.concatenate(w)

    def loss(beta):
        p = 1.0 / (1.0 + np.exp(-(x @ beta)))
        return -float(np.sum(w * (y * np.log(p + 1e-9) + (1 - y) * np.log(1 - p + 1e-9)))) + 1e-4 * beta @ beta

    return minimize(loss, np.zeros(x.shape[1]), method="L-BFGS-B").x


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labels", type=Path, required=True, help="folder of cached labels (vote_select.py's)")
    args = parser.parse_args()
    entries = [e for e in labelled() if e.name.startswith("samp")]
    samples = {e.name: sample(e, args.labels) for e in entries}
    train = [n for n, s in samples.items() if s["split"] == "train"]

    lines = ["# The vote's disagreements: can they be labelled better than by the majority?", "",
             "Command: `nice .venv/bin/python experiments/vote_disagreements.py --labels /tmp/vote_labels` "
             "(the module docstring says what each rule is). The 11 ISPRS samples, each voter with its "
             "defaults.", "", "Per voter pattern (SMRF, MASF, PMF: 1 = ground), summed over the samples "
             "of each sample's share of its scored points [%]: ground / non-ground points.", "",
             "| pattern | ground % | non-ground % | the majority says | its error % |", "| --- | ---: | ---: | --- | ---: |"]
    oracle = {}
    for code in range(8):
        bits = tuple(bool(code >> (2 - i) & 1) for i in range(3))
        g = ng = 0.0
        for s in samples.values():
            here = np.all(s["votes"].T == bits, axis=1) & s["scored"]
            g += 100 * (here & s["reference"]).sum() / s["scored"].sum()
            ng += 100 * (here & ~s["reference"]).sum() / s["scored"].sum()
        says = sum(bits) >= 2
        oracle[bits] = ng < g
        lines.append(f"| {''.join(str(int(b)) for b in bits)} | {g:.2f} | {ng:.2f} | "
                     f"{'ground' if says else 'non-ground'} | {ng if says else g:.2f} |")

    rows = [("majority (the vote)", {n: total_error(s["count"] >= 2, s) for n, s in samples.items()})]
    rows.append(("hindsight bound: the better label per pattern, on all 11",
                 {n: total_error(np.array([oracle[tuple(v)] for v in s["votes"].T]), s) for n, s in samples.items()}))
    rule = {"abs(h) < t": lambda s, t: np.abs(s["h"]) < t, "h < t": lambda s, t: s["h"] < t,
            "neighbour share > t": lambda s, t: s["share"] > t}
    for name, fn in rule.items():
        best = min(THRESHOLDS[name], key=lambda t: np.mean([total_error(relabel(samples[n], fn(samples[n], t)),
                                                                       samples[n]) for n in train]))
        rows.append((f"{name}, t = {best} (best on the training samples)",
                     {n: total_error(relabel(s, fn(s, best)), s) for n, s in samples.items()}))
    held = {}
    for n, s in samples.items():
        beta = fit_logistic([samples[m] for m in train if samples[m]["survey"] != s["survey"]])
        held[n] = total_error(relabel(s, features(s) @ beta > 0), s)
    rows.append(("logistic model, leave one survey out", held))
    rows.append(("the spike guard again, on the vote's labels",
                 {n: total_error(s["guarded"], s) for n, s in samples.items()}))

    names = list(samples)
    lines += ["", "Total error % of each rule on each sample:", "",
              "| rule | " + " | ".join(names) + " | mean, 8 training | mean, 11 |",
              "| --- |" + " ---: |" * (len(names) + 2)]
    for name, te in rows:
        lines.append(f"| {name} | " + " | ".join(f"{te[n]:.2f}" for n in names)
                     + f" | {np.mean([te[n] for n in train]):.2f} | {np.mean(list(te.values())):.2f} |")
    majority, bound = rows[0][1], rows[1][1]
    best = min(rows[2:], key=lambda r: np.mean(list(r[1].values())))
    lines += ["", f"- The majority: {np.mean(list(majority.values())):.2f} % over the 11 samples. With every "
              f"disagreement pattern given its better label in hindsight: {np.mean(list(bound.values())):.2f} %, "
              "so the voters' labels alone cannot take the vote much lower.",
              f"- The best rule that reads more than the labels: {best[0]}, {np.mean(list(best[1].values())):.2f} %."]
    write_markdown(RESULTS / "vote_disagreements.md", lines)


if __name__ == "__main__":
    main()
