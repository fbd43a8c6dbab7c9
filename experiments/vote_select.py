"""Which classical filters a majority vote should join, chosen on training files only.

Candidates: SMRF alone, and the majority of SMRF with any two to four of MASF, PMF, CSF and
DMF, each run with its defaults (a tie, with an even number of voters, goes to SMRF). The
rule reads training files only: among the candidates that pass every training
file of a fold (type I <= 10 %, DTM RMSE <= 0.30 m, as `corpus_eval`), the one with the lowest
mean total error on the fold's ISPRS training samples; a tie goes to fewer voters.

Estimates: leave one survey out (the rule chooses on the other surveys' training files and
the held-out survey's files are scored); the test files are scored with the candidate the
rule picks on every training file.

The default leaves out a voter that covers a whole file at once (`Method.whole_cloud`: CSF's
cloth, about 10 GiB for a 2 x 2 km tile): the same rule among the candidates without one.
The rule and that constraint were written after a first look at majority votes on all 11
ISPRS samples, test samples included, so both rules are estimated the same way, leaving each
survey out, and reported side by side.

    nice .venv/bin/python experiments/vote_select.py --labels /tmp/vote_labels

Labels of each method on each file are kept in `--labels` (one `.npy` per method and file),
so a rerun scores again without filtering again.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled, write_markdown  # noqa: E402
from experiments.corpus_eval import CELL_M, passes  # noqa: E402

FIRST = "smrf"
OTHERS = ("masf", "pmf", "csf", "dmf")
CANDIDATES: tuple[tuple[str, ...], ...] = ((FIRST,), *((FIRST, *c) for r in (2, 3, 4)
                                                       for c in itertools.combinations(OTHERS, r)))


def labels(method: str, entry, folder: Path) -> np.ndarray:
    """Bool `(n,)` ground labels of `method`'s defaults on one labelled file (cached in `folder`)."""
    path = folder / f"{method}_{entry.name}.npy"
    if not path.exists():
        import gfjax
        from gfjax import methods

        cloud = gfjax.read(entry.file)
        ground = np.asarray(methods.get(method).filter(cloud, progress=False).ground, dtype=bool)
        folder.mkdir(parents=True, exist_ok=True)
        np.save(path, ground)
        print(f"{method:5s} {entry.name}", flush=True)
    return np.load(path)


def vote(votes: list[np.ndarray]) -> np.ndarray:
    """Majority of bool `(n,)` label arrays; a tie goes to the first."""
    count = np.sum(votes, axis=0)
    return np.where(2 * count == len(votes), votes[0], 2 * count > len(votes))


def score(entry, ground: np.ndarray) -> dict:
    import gfjax
    from gfjax import metrics

    cloud = gfjax.read(entry.file)
    reference, scored = cloud.classification == 2, metrics.scored_mask(cloud.classification)
    point = metrics.point_metrics(ground, reference, mask=scored)
    dtm = metrics.dtm_metrics(cloud.xyz_m, ground, reference, cell_m=CELL_M, mask=scored)
    row = {"total_error": point["total_error"], "type1": point["type1"], "type2": point["type2"],
           "rmse_m": dtm["rmse_m"]}
    row["passes"] = passes(row)
    return row


def scales(candidate: tuple[str, ...]) -> bool:
    """Whether no voter of `candidate` covers a whole file at once (`Method.whole_cloud`)."""
    from gfjax import methods

    return not any(methods.get(name).whole_cloud for name in candidate)


def choose(table: dict, files: list, *, scaling: bool = False) -> tuple[str, ...]:
    """The rule (module docstring) on `files`, training files only; `scaling`: among the
    candidates that `scales` only."""
    isprs = [e.name for e in files if e.name.startswith("samp")]

    def key(candidate):
        rows = table[candidate]
        sound = all(rows[e.name]["passes"] for e in files)
        return (not sound, float(np.mean([rows[n]["total_error"] for n in isprs])), len(candidate))

    return min([c for c in CANDIDATES if scales(c) or not scaling], key=key)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--labels", type=Path, required=True, help="folder of cached labels")
    parser.add_argument("--json", type=Path, default=RESULTS / "vote_select.json")
    args = parser.parse_args()
    files = labelled()
    table: dict[tuple[str, ...], dict[str, dict]] = {c: {} for c in CANDIDATES}
    for entry in files:
        runs = {m: labels(m, entry, args.labels) for m in (FIRST, *OTHERS)}
        for candidate in CANDIDATES:
            table[candidate][entry.name] = score(entry, vote([runs[m] for m in candidate]))
    train = [e for e in files if e.split == "train"]
    doc: dict = {"candidates": {"+".join(c): table[c] for c in CANDIDATES}, "rules": {}}
    for rule, scaling in (("every candidate", False), ("voters that scale with the tile", True)):
        chosen = choose(table, train, scaling=scaling)
        held: dict[str, dict] = {}
        for survey in sorted({e.survey for e in files}):
            picked = choose(table, [e for e in train if e.survey != survey], scaling=scaling)
            for e in files:
                if e.survey == survey:
                    voters = picked if e.split == "train" else chosen
                    held[e.name] = {"picked": "+".join(voters), **table[voters][e.name]}
        doc["rules"][rule] = {"chosen": "+".join(chosen), "held_out": held}
    args.json.write_text(json.dumps(doc, indent=1))
    write_markdown(args.json.with_suffix(".md"), markdown(doc, files))


def markdown(doc: dict, files: list) -> list[str]:
    isprs = [e.name for e in files if e.name.startswith("samp")]
    train = [e.name for e in files if e.split == "train"]
    cands = doc["candidates"]
    chosen = {rule: r["chosen"] for rule, r in doc["rules"].items()}
    lines = ["# A majority vote of classical filters: which voters", "",
             "Command: `nice .venv/bin/python experiments/vote_select.py --labels /tmp/vote_labels`. "
             "Each method with its defaults; the rule and the folds: `experiments/vote_select.py`.", "",
             *(f"- Chosen on every training file among {rule}: **{c}**." for rule, c in chosen.items()), "",
             "| voters | scales with the tile | training files passed | files passed | "
             "ISPRS mean total error % (8 train / all 11) | mean total error % (29 files) | mean type I % | "
             "mean DTM RMSE m |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    tr = [n for n in isprs if n in train]
    for name, rows in sorted(cands.items(), key=lambda kv: np.mean([kv[1][n]["total_error"] for n in isprs])):
        lines.append(f"| {name} | {'yes' if scales(tuple(name.split('+'))) else 'no'} | "
                     f"{sum(rows[n]['passes'] for n in train)}/{len(train)} | "
                     f"{sum(r['passes'] for r in rows.values())}/{len(rows)} | "
                     f"{100 * np.mean([rows[n]['total_error'] for n in tr]):.2f} / "
                     f"{100 * np.mean([rows[n]['total_error'] for n in isprs]):.2f} | "
                     f"{100 * np.mean([r['total_error'] for r in rows.values()]):.2f} | "
                     f"{100 * np.mean([r['type1'] for r in rows.values()]):.2f} | "
                     f"{np.mean([r['rmse_m'] for r in rows.values()]):.3f} |")
    rules = list(doc["rules"])
    lines += ["", "Leave one survey out: a training file scored with the voters the rule chose without its "
              "survey, a test file with those it chose on every training file. Total error % / type I % / "
              "DTM RMSE m (voters where they differ from the rule's choice on every training file):", "",
              "| file | split | " + " | ".join(rules) + " |", "| --- | --- |" + " --- |" * len(rules)]
    for e in files:
        cells = []
        for rule in rules:
            r = doc["rules"][rule]["held_out"][e.name]
            other = "" if r["picked"] == chosen[rule] else f" ({r['picked']})"
            text = f"{100 * r['total_error']:.2f} / {100 * r['type1']:.2f} / {r['rmse_m']:.3f}{other}"
            cells.append(text if r["passes"] else f"**{text}**")
        lines.append(f"| {e.name} | {e.split} | " + " | ".join(cells) + " |")
    lines.append("")
    for rule in rules:
        held = doc["rules"][rule]["held_out"]
        lines.append(f"- {rule}: ISPRS mean total error held out {100 * np.mean([held[n]['total_error'] for n in isprs]):.2f} % "
                     f"(11 samples), files passed held out {sum(r['passes'] for r in held.values())}/{len(held)}.")
    return lines


if __name__ == "__main__":
    main()
