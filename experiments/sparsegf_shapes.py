"""How many programs SparseGF training compiles: the padded shapes of one epoch's batches.

    nice .venv/bin/python experiments/sparsegf_shapes.py

One epoch's patches of the training split of `experiments/results/sparsegf_model.md` (the
same files, seed 0, batches of 4), grouped as `gfjax.sparsegf.train.training_batches` groups
them: each distinct `(points, voxels, pyramid plan)` is one compile of the training step. A
batch whose patches do not fit their capacity's standard plan is planned again from the data
(`pipeline.grow_plan`), which adds a shape. Writes `experiments/results/sparsegf_shapes.md`.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from gfjax.io import las as las_io
from gfjax.sparsegf import pipeline, train
from gfjax.sparsegf.config import Config

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
ISPRS = DATA / "isprs_filtertest" / "reference"
FILES = [*(ISPRS / f"samp{s}-utm.laz" for s in (12, 21, 24, 41, 51, 52, 71)), DATA / "lasR_bcts" / "bcts_1.laz",
         DATA / "lidR_topography" / "Topography.laz", DATA / "pdal_autzen" / "autzen_trim.laz"]


def main():
    start = time.perf_counter()
    data = []
    for path in FILES:
        cloud = las_io.read(path)
        data.append(train.labelled(cloud.xyz_m, cloud.classification))
    plans, shapes, batches, grown = {}, set(), 0, 0
    for batch, _, _ in train.training_batches(data, Config(), batch_size=4, rng=np.random.default_rng([0, 0]),
                                              plans=plans):
        fitted = pipeline.grow_plan(batch)
        if fitted.plan != batch.plan:
            grown += 1
            plans[batch.plan.capacities[0]] = fitted.plan
            batch = fitted
        shapes.add((batch.patch.index.shape, batch.patch.coords.shape, batch.plan))
        batches += 1
    seconds = time.perf_counter() - start
    lines = ["# SparseGF training: programs compiled per epoch", "",
             "Command: `nice .venv/bin/python experiments/sparsegf_shapes.py`  ",
             f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU; "
             f"{seconds:.0f} s.", "",
             f"- batches in one epoch: {batches}",
             f"- batches that did not fit their capacity's standard plan (planned again from the data): {grown}",
             f"- distinct (points, voxels, plan) shapes, i.e. compiles of the training step: {len(shapes)}",
             "", "| points x voxels (batch, rows) | plan capacities |", "| --- | --- |"]
    for index_shape, coords_shape, plan in sorted(shapes, key=str):
        lines.append(f"| {index_shape} x {coords_shape[:2]} | {plan.capacities} |")
    out = ROOT / "experiments" / "results" / "sparsegf_shapes.md"
    out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
