"""The halo a survey gives each file of a method that does not tile: labels against its width.

    nice .venv/bin/python experiments/survey_halo.py [--methods dmf] [--halos 50,20,10,5,own] [--files bcts_1,...]

Each training file (`experiments.common.LABELLED`, split "train": no test file picks the
halo) is cut into 3 x 3 files at its x and y terciles (`survey_seams.py`'s cut), filtered as
one file and as a survey of its 9 parts (`gfjax.survey.filtered`) with each halo width
(`gfjax.survey.run.halo_width` set for the run; "own": the method's own,
`gfjax.survey.halo_width`, the width a survey takes), both with the method's fixed `Config()` so the
seams alone differ. The table gives the share of points whose survey label equals the one
file's, and the survey's process CPU time. Writes `experiments/results/survey_halo.md` (and
`.json`).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np
from common import LABELLED, RESULTS

from gfjax import methods, survey
from gfjax.io import las as las_io
from gfjax.survey import halo
from gfjax.survey import run as survey_run


def cut(source: Path, folder: Path) -> tuple[list[Path], list[np.ndarray]]:
    """`source` cut into 3 x 3 files at its coordinate terciles; the files and each one's
    indices into `source`."""
    las = laspy.read(source)
    x, y = np.asarray(las.x), np.asarray(las.y)
    xi = np.digitize(x, np.quantile(x, [1 / 3, 2 / 3]))
    yi = np.digitize(y, np.quantile(y, [1 / 3, 2 / 3]))
    files, members = [], []
    for i in range(3):
        for j in range(3):
            keep = np.flatnonzero((xi == i) & (yi == j))
            target = folder / f"{source.stem}_{i}{j}.laz"
            laspy.LasData(header=las.header, points=las.points[keep].copy()).write(target)
            files.append(target)
            members.append(keep)
    return files, members


def _fresh(folder: Path) -> Path:
    folder.mkdir()
    return folder


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="dmf")
    parser.add_argument("--halos", default="50,20,10,5,own")
    parser.add_argument("--files", default="bcts_1,Topography,autzen,samp51")
    args = parser.parse_args()
    chosen = {f.name: f for f in LABELLED}
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax-halo-") as tmp:
        for name in args.files.split(","):
            if chosen[name].split != "train":
                raise SystemExit(f"{name}: not a training file")
            folder = Path(tmp) / name
            folder.mkdir()
            files, members = cut(chosen[name].file, folder)
            whole = las_io.read(chosen[name].file)
            for method_name in args.methods.split(","):
                module = methods.get(method_name)
                config = module.Config()
                want = np.asarray(module.filter(whole, config=config).ground)
                for given in args.halos.split(","):
                    if given == "own":
                        catalog = survey.index(files, _fresh(folder / f"own_{method_name}"))
                        width = halo.halo_width(module, survey.survey_config(module, config, catalog))
                    else:
                        width = float(given)
                    survey_run.halo_width = lambda method, config, width=width: width    # what `filtered` takes
                    got = np.zeros(whole.n_points, bool)
                    store = folder / f"store_{method_name}_{given}"
                    store.mkdir()
                    cpu = time.process_time()
                    for (_, result), keep in zip(survey.filtered(files, module, store, config=config), members):
                        got[keep] = result.ground
                    row = {"file": name, "method": method_name, "points": whole.n_points, "halo_m": width,
                           "own": given == "own",
                           "equal_pct": 100 * float(np.mean(got == want)), "cpu_s": time.process_time() - cpu}
                    rows.append(row)
                    print(row, flush=True)
    lines = ["# Survey halo: labels of a method that does not tile against the halo's width", "",
             f"Command: `nice .venv/bin/python experiments/survey_halo.py --methods {args.methods} "
             f"--halos {args.halos} --files {args.files}`  ",
             f"Load average at the end: {' '.join(f'{v:.1f}' for v in os.getloadavg())}; 2-core CPU. Each training "
             "file cut into 3 x 3 files; fixed `Config()` on both sides. CPU: the survey's process time (the "
             "first width of each file also pays its compiles).", "",
             "| file | method | points | halo m | survey = one file [%] | survey CPU s |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        width = f"{r['halo_m']:g}" + (" (own)" if r.get("own") else "")
        lines.append(f"| {r['file']} | {r['method']} | {r['points']:,} | {width} | {r['equal_pct']:.4f} | "
                     f"{r['cpu_s']:.1f} |")
    (RESULTS / "survey_halo.md").write_text("\n".join(lines) + "\n")
    (RESULTS / "survey_halo.json").write_text(json.dumps(rows, indent=1) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
