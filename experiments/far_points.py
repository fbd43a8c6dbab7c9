"""A stray point far from the others: time and peak memory of every method, with and without it.

    .venv/bin/python experiments/far_points.py [--distance-m 10000] [--methods smrf pmf csf dmf masf]

20,000 points over 140 m x 140 m (flat ground, 0.1 m noise), then the same plus one point
`--distance-m` away to the north-east. Each run is a fresh process (`GFJAX_CACHE=0`, so
every run compiles alike) that reports its filter call's time and its peak resident memory.
Every method moves groups of points far apart side by side before it builds a raster
(`gfjax.io.groups`); the labels of the 20,000 points are compared between the two runs.
Writes `experiments/results/far_points.md`.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "experiments" / "results"

_PROGRAM = r"""
import importlib, resource, sys, time
import numpy as np, gfjax
method = importlib.import_module("gfjax." + sys.argv[1])
rng = np.random.default_rng(0)
xy = rng.uniform(0, 140, (20000, 2))
z = 100 + rng.normal(0, 0.1, len(xy))
if float(sys.argv[2]) > 0:
    xy, z = np.vstack([xy, [[float(sys.argv[2])] * 2]]), np.append(z, 100.0)
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z]))
start = time.perf_counter()
ground = method.filter(cloud).ground
seconds = time.perf_counter() - start
np.save(sys.argv[3], ground[:20000])
print(seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def run(method: str, distance_m: float, out: str) -> tuple[float, float]:
    """`(seconds of the filter call, peak memory [GB])` of one fresh process."""
    env = {**os.environ, "GFJAX_CACHE": "0"}
    done = subprocess.run([sys.executable, "-c", _PROGRAM, method, str(distance_m), out], capture_output=True,
                          text=True, cwd=ROOT, env=env, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"{method}: {done.stderr.strip().splitlines()[-1]}")
    seconds, kib = done.stdout.split()
    return float(seconds), int(kib) / 1024 ** 2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distance-m", type=float, default=10_000.0)
    parser.add_argument("--methods", nargs="+", default=["smrf", "pmf", "csf", "dmf", "masf"])
    args = parser.parse_args()
    lines = ["# A stray point far from the others", "",
             f"Command: `.venv/bin/python experiments/far_points.py --distance-m {args.distance_m:g}`  ",
             "20,000 points over 140 m x 140 m, then the same plus one point "
             f"{args.distance_m:,.0f} m away in x and y; a fresh process per run (compiles included).  ",
             f"Load average at the start: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU.", "",
             "| method | filter call [s] alone | with the stray point | peak memory [GB] alone | with | "
             "labels of the 20,000 equal |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    tmp = RESULTS / ".far_points"
    tmp.mkdir(exist_ok=True)
    for method in args.methods:
        alone = run(method, 0.0, str(tmp / "alone.npy"))
        far = run(method, args.distance_m, str(tmp / "far.npy"))
        same = np.mean(np.load(tmp / "alone.npy") == np.load(tmp / "far.npy"))
        lines.append(f"| {method} | {alone[0]:.1f} | {far[0]:.1f} | {alone[1]:.2f} | {far[1]:.2f} | {100 * same:.2f} % |")
        print(lines[-1], flush=True)
    for name in ("alone.npy", "far.npy"):
        (tmp / name).unlink(missing_ok=True)
    tmp.rmdir()
    (RESULTS / "far_points.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
