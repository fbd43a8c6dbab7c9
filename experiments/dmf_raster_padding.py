"""DMF's raster stages (steps 4-6) on one NGNEM padded two ways: to the smallest canonical
square, and each axis to its own canonical side (`gfjax.dmf.shapes.raster_shape`).

    .venv/bin/python experiments/dmf_raster_padding.py [--file PATH] [--runs 7]

Runs DMF once on the file (default `lasR_bcts/bcts_2.laz` of the shared data) for its NGNEM,
then times the jitted raster stages on that NGNEM under both paddings, alternated, compiled
once each beforehand; prints the medians and checks that both give the same rasters on the
NGNEM's own cells. Writes `experiments/results/dmf_raster_padding.md`.
"""
from __future__ import annotations

import argparse
import functools
import importlib
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402
import numpy as np  # noqa: E402

from experiments.common import DATA, RESULTS  # noqa: E402
from gfjax.dmf import programs, shapes, stages  # noqa: E402
from gfjax.dmf.config import Config  # noqa: E402
from gfjax.io import las  # noqa: E402
from gfjax.tiling.buckets import canonical_square  # noqa: E402

dmf_filter = importlib.import_module("gfjax.dmf.filter")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", type=Path, default=DATA / "lasR_bcts" / "bcts_2.laz")
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    config = Config()
    d = dmf_filter.filter(las.read(args.file), config=config).diagnostics
    vox, cell_m = d.voxels, d.cell_m
    h, w = vox.shape
    z, k, v = np.zeros(h * w, np.float32), np.zeros(h * w, np.int32), np.zeros(h * w, bool)
    z[vox.cell], k[vox.cell], v[vox.cell] = vox.centroid[:, 2], vox.layer, True
    shapes_by_name = {"square": canonical_square((h, w), shapes.raster_sides(cell_m)),
                      "axis by axis": shapes.raster_shape((h, w), cell_m)}
    run = jax.jit(functools.partial(stages.raster_stages, **programs.stage_options(config)))
    tiles = {name: dmf_filter._pad_tile(z.reshape(h, w), k.reshape(h, w), v.reshape(h, w), shape)
             for name, shape in shapes_by_name.items()}
    scalars = (np.float32(cell_m), np.float32(config.rc_min_share))
    outs = {name: jax.block_until_ready(run(*tile, *scalars)) for name, tile in tiles.items()}
    for field in ("ngnem", "rhc", "ngnem_bi", "ngnem_rc", "instances"):
        a, b = (np.asarray(getattr(out, field))[:h, :w] for out in outs.values())
        assert np.array_equal(a, b), f"{field} differs between the paddings"
    seconds = {name: [] for name in tiles}
    for _ in range(args.runs):
        for name, tile in tiles.items():
            start = time.perf_counter()
            jax.block_until_ready(run(*tile, *scalars))
            seconds[name].append(time.perf_counter() - start)
    lines = ["# DMF's raster stages: square padding against axis-by-axis padding", "",
             f"Command: `.venv/bin/python experiments/dmf_raster_padding.py --runs {args.runs}` "
             f"(file {args.file.name}); NGNEM {h} x {w} cells at W = {cell_m:g} m; medians of {args.runs} alternated warm calls. "
             "Both paddings give the same rasters on the NGNEM's cells.", "",
             "| padding | padded shape | cells | s (median) |", "| --- | --- | ---: | ---: |"]
    for name, shape in shapes_by_name.items():
        lines.append(f"| {name} | {shape[0]} x {shape[1]} | {shape[0] * shape[1]:,} | "
                     f"{statistics.median(seconds[name]):.3f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    (RESULTS / "dmf_raster_padding.md").write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
