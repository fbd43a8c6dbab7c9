"""Points far from each other: time and peak memory of every method, with and without a stray point, and spread thin.

    .venv/bin/python experiments/far_points.py [--distance-m 10000] [--spread-km 100] [--methods smrf pmf csf dmf masf]

20,000 points over 140 m x 140 m (flat ground, 0.1 m noise), then the same plus one point
`--distance-m` away to the north-east, then the 20,000 points spread uniformly over
`--spread-km` x `--spread-km`. Each run is a fresh process (`GFJAX_CACHE=0`, so every run
compiles alike) that reports its filter call's time and its peak resident memory. The
whole-cloud methods move groups of points far apart side by side before they build a raster,
the tiled ones filter each group as a cloud of its own (`gfjax.tiling.groups`,
`gfjax.tiling.driver.classify_groups`); the labels of the 20,000 points are compared between the
first two runs. Writes `experiments/results/far_points.md`.
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

# A fresh process that times its own filter call with the plain clock and reports its own peak
# memory (read by `run`): the harness is not imported there, so it adds nothing to that memory.
_PROGRAM = r"""
import importlib, resource, sys, time
import numpy as np, gfjax
method = importlib.import_module("gfjax." + sys.argv[1])
rng = np.random.default_rng(0)
xy = rng.uniform(0, 140, (20000, 2))
z = 100 + rng.normal(0, 0.1, len(xy))
if float(sys.argv[4]) > 0:
    xy = rng.uniform(0, float(sys.argv[4]), (20000, 2))
if float(sys.argv[2]) > 0:
    xy, z = np.vstack([xy, [[float(sys.argv[2])] * 2]]), np.append(z, 100.0)
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + [5e5, 5e6], z]))
start = time.perf_counter()
ground = method.filter(cloud).ground
seconds = time.perf_counter() - start
np.save(sys.argv[3], ground[:20000])
print(seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
"""


def run(method: str, distance_m: float, out: str, spread_m: float = 0.0, *, refused_ok: bool = False) -> tuple[float, float] | str:
    """`(seconds of the filter call, peak memory [GB])` of one fresh process (its error line
    when `refused_ok` and it fails)."""
    env = {**os.environ, "GFJAX_CACHE": "0"}
    done = subprocess.run([sys.executable, "-c", _PROGRAM, method, str(distance_m), out, str(spread_m)],
                          capture_output=True, text=True, cwd=ROOT, env=env, timeout=1800)
    if done.returncode != 0:
        line = done.stderr.strip().splitlines()[-1]
        if refused_ok:
            return line
        raise SystemExit(f"{method}: {line}")
    seconds, kib = done.stdout.split()
    return float(seconds), int(kib) / 1024 ** 2


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--distance-m", type=float, default=10_000.0)
    parser.add_argument("--spread-km", type=float, default=100.0)
    parser.add_argument("--methods", nargs="+", default=["smrf", "pmf", "csf", "dmf", "masf"])
    args = parser.parse_args()
    lines = ["# A stray point far from the others", "",
             f"Command: `.venv/bin/python experiments/far_points.py --distance-m {args.distance_m:g} "
             f"--spread-km {args.spread_km:g}`  ",
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
    lines += ["", f"## The 20,000 points spread over {args.spread_km:g} km x {args.spread_km:g} km", "",
              "| method | filter call [s] | peak memory [GB] | ground |", "| --- | ---: | ---: | ---: |"]
    for method in args.methods:
        done = run(method, 0.0, str(tmp / "spread.npy"), args.spread_km * 1000.0, refused_ok=True)
        if isinstance(done, str):
            lines.append(f"| {method} | refused: {done} | | |")
        else:
            share = np.mean(np.load(tmp / "spread.npy"))
            lines.append(f"| {method} | {done[0]:.1f} | {done[1]:.2f} | {100 * share:.1f} % |")
        print(lines[-1], flush=True)
    for name in ("alone.npy", "far.npy", "spread.npy"):
        (tmp / name).unlink(missing_ok=True)
    tmp.rmdir()
    (RESULTS / "far_points.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
