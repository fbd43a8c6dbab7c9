"""The low-outlier detector (`gfjax.low_outliers`) on the training files: what it flags, and how
much of it is reference ground.

    nice .venv/bin/python experiments/low_outliers.py [--set NAME=VALUE ...]

On every *training* file of `experiments.common.LABELLED` (test files are never read here):
the points flagged, the reference ground (class 2) among them, and the "deep" points, non-ground
points more than `DEEP_M` below the reference ground's TIN (`gfjax.dtm.hag`), which the detector
should catch; with the seconds of the `detect` call. The detector sees what a method sees: the
used points (noise and withheld left out) and the last-return spacing of `gfjax.adaptive.measure`.
`--set THRESHOLD_M=3` tries another value of a module constant (a trial: the results file says so).
Writes `experiments/results/low_outliers.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import RESULTS, labelled, write_markdown  # noqa: E402
from gfjax.bench.harness import Stopwatch  # noqa: E402

DEEP_M = 2.0        # a non-ground point this far below the reference ground is a low outlier to catch [m]


def file_row(entry) -> dict:
    """Flags and their truth on one labelled file."""
    import gfjax
    from gfjax import adaptive, low_outliers, metrics
    from gfjax.dtm.hag import height_above_ground

    cloud = gfjax.read(entry.file)
    xyz = cloud.xyz_m
    used = cloud.filter_mask("all")
    terrain = adaptive.measure(xyz[used], xyz[cloud.filter_mask("last")])
    with Stopwatch() as watch:
        low = low_outliers.detect(xyz, used, last_spacing_m=terrain.last_spacing_m)
    ground = cloud.classification == 2
    scored = metrics.scored_mask(cloud.classification)         # water, noise, overlap left out
    deep = used & scored & ~ground & (height_above_ground(xyz, ground) < -DEEP_M)
    return {"file": entry.name, "points": int(used.sum()), "ground": int(ground.sum()),
            "cell_m": low_outliers.cell_m(terrain.last_spacing_m), "flagged": int(low.sum()),
            "flagged_ground": int((low & ground).sum()), "deep": int(deep.sum()), "deep_caught": int((low & deep).sum()),
            "seconds": watch.wall_s}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--set", dest="values", action="append", default=[], metavar="NAME=VALUE",
                        help="another value of a constant of gfjax.low_outliers (a trial)")
    parser.add_argument("--out", type=Path, default=RESULTS / "low_outliers.md")
    args = parser.parse_args()
    from gfjax import low_outliers

    for item in args.values:
        name, value = item.split("=", 1)
        setattr(low_outliers, name, type(getattr(low_outliers, name))(value))
    rows = []
    for entry in labelled("train"):
        row = file_row(entry)
        rows.append(row)
        print(f"{row['file']:12s} flagged {row['flagged']:6d} ground {row['flagged_ground']:5d} "
              f"deep {row['deep_caught']:5d}/{row['deep']:5d} {row['seconds']:.2f} s", flush=True)
    constants = {k: getattr(low_outliers, k) for k in low_outliers.__all__ if k.isupper()}
    args.out.with_suffix(".json").write_text(json.dumps({"constants": constants, "deep_m": DEEP_M, "files": rows},
                                                        indent=1))
    command = "nice .venv/bin/python experiments/low_outliers.py" + "".join(f" --set {v}" for v in args.values)
    lines = ["# Low outliers flagged on the training files", "",
             f"Command: `{command}`. Detector `gfjax.low_outliers.detect` with "
             + ", ".join(f"{k} = {v}" for k, v in constants.items())
             + f". *Deep*: non-ground points more than {DEEP_M:g} m below the reference ground's TIN (to catch; water, noise and overlap classes left out, as in the scores); "
             "*ground flagged*: reference ground (class 2) flagged (to keep at none). Test files are not read.", "",
             "| file | used points | cell m | flagged | ground flagged | % of ground | deep caught / deep | seconds |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['file']} | {r['points']:,} | {r['cell_m']:.2f} | {r['flagged']:,} | {r['flagged_ground']:,} | "
                     f"{100 * r['flagged_ground'] / max(1, r['ground']):.3f} | {r['deep_caught']:,} / {r['deep']:,} | "
                     f"{r['seconds']:.2f} |")
    total = {k: sum(r[k] for r in rows) for k in ("flagged", "flagged_ground", "deep", "deep_caught")}
    lines += ["", f"All {len(rows)} files: {total['flagged']:,} flagged, {total['flagged_ground']:,} of them reference "
              f"ground; {total['deep_caught']:,} of {total['deep']:,} deep points caught "
              f"(the per-file rows say where the others are)."]
    write_markdown(args.out, lines)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
