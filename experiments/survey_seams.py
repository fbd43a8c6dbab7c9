"""Seams: a survey cut into a 3 x 3 grid of files, filtered as a catalog and one file at a time.

    nice .venv/bin/python experiments/survey_seams.py [--methods smrf,pmf,...]

The union of the forest tiles `bcts_1` and `bcts_2` (../shared/data/lasR_bcts) is written as
one file and cut into 3 x 3 files at its x and y terciles (same point format, scales and
offsets). Each method filters (a) the union as one file, (b) the 9 files as a survey
(`gfjax filter` with several inputs: each file with its neighbours' halo on the survey's
frame) and (c) the 9 files independently (`--independent`), all with default settings; the
table gives the share of points whose label in (b) and (c) equals (a), and the wall time of
each run. Writes `experiments/results/survey_seams.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import laspy
import numpy as np

from gfjax import methods, survey
from gfjax.bench.harness import Stopwatch
from gfjax.io import las as las_io

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
SOURCES = (DATA / "lasR_bcts" / "bcts_1.laz", DATA / "lasR_bcts" / "bcts_2.laz")
RESULTS = ROOT / "experiments" / "results"


def write_survey(folder: Path) -> tuple[Path, list[Path], list[np.ndarray]]:
    """The union file and its 3 x 3 grid of files; each file's indices into the union."""
    parts = [laspy.read(p) for p in SOURCES]
    header = parts[0].header
    union = laspy.LasData(header=laspy.LasHeader(point_format=header.point_format, version=header.version))
    union.header.scales, union.header.offsets = header.scales, header.offsets
    union.points = laspy.ScaleAwarePointRecord.zeros(sum(len(p.points) for p in parts), header=union.header)
    start = 0
    for p in parts:
        n = len(p.points)
        for name in p.point_format.dimension_names:
            if name in ("X", "Y", "Z"):
                continue
            union[name][start:start + n] = p[name]
        union.x[start:start + n], union.y[start:start + n], union.z[start:start + n] = p.x, p.y, p.z
        start += n
    for vlr in header.vlrs:
        union.header.vlrs.append(vlr)
    path = folder / "union.laz"
    union.write(path)
    union = laspy.read(path)
    xi = np.digitize(union.x, np.quantile(union.x, [1 / 3, 2 / 3]))
    yi = np.digitize(union.y, np.quantile(union.y, [1 / 3, 2 / 3]))
    files, members = [], []
    for i in range(3):
        for j in range(3):
            keep = np.flatnonzero((xi == i) & (yi == j))
            out = laspy.LasData(header=union.header, points=union.points[keep].copy())
            target = folder / f"grid_{i}{j}.laz"
            out.write(target)
            files.append(target)
            members.append(keep)
    return path, files, members


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="smrf,pmf,csf,dmf,masf")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax-seams-") as tmp:
        folder = Path(tmp)
        union_path, files, members = write_survey(folder)
        union = las_io.read(union_path)
        for name in args.methods.split(","):
            module = methods.get(name)
            with Stopwatch() as watch:
                want = np.asarray(module.filter(union).ground)
            union_s = watch.wall_s
            catalog = np.zeros(union.n_points, bool)
            alone = np.zeros(union.n_points, bool)
            with Stopwatch() as watch:
                store = folder / f"store_{name}"
                store.mkdir()
                for (_, result), keep in zip(survey.filtered(files, module, store), members):
                    catalog[keep] = result.ground
            catalog_s = watch.wall_s
            with Stopwatch() as watch:
                for path, keep in zip(files, members):
                    alone[keep] = module.filter(las_io.read(path)).ground
            alone_s = watch.wall_s
            row = {"method": name, "points": union.n_points, "catalog_equal_pct": 100 * float(np.mean(catalog == want)),
                   "independent_equal_pct": 100 * float(np.mean(alone == want)), "union_s": union_s,
                   "catalog_s": catalog_s, "independent_s": alone_s}
            rows.append(row)
            print(row, flush=True)
            write_results(rows)          # after every method: an interrupted run keeps its rows


def write_results(rows: list[dict]) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "survey_seams.json").write_text(json.dumps(rows, indent=2) + "\n")
    lines = ["# Seams: bcts_1 + bcts_2 cut into 3 x 3 files", "",
             "Command: `nice .venv/bin/python experiments/survey_seams.py`  ",
             f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU. "
             "Times include the first call's compiles (the union runs first).", "",
             "| method | points | survey (catalog) = one file [%] | files alone = one file [%] | "
             "one file [s] | survey [s] | files alone [s] |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['points']:,} | {r['catalog_equal_pct']:.4f} | {r['independent_equal_pct']:.4f} "
                     f"| {r['union_s']:.1f} | {r['catalog_s']:.1f} | {r['independent_s']:.1f} |")
    (RESULTS / "survey_seams.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
