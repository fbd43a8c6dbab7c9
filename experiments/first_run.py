"""Time to first result: what canonical shapes cost while running, and what `gfjax warmup` saves.

    nice .venv/bin/python experiments/first_run.py gfjax/data/samp12-utm.laz \\
        ../shared/data/lidR_topography/Topography.laz ../shared/data/lasR_bcts/bcts_1.laz \\
        ../shared/data/isprs_filtertest/reference/samp41-utm.laz --runs 5 \\
        -o experiments/results/canonical_shapes.md

1. Padding cost, in one process with warm programs: `<method>.filter` on each file with the
   canonical shapes (`gfjax.tiling.buckets.canonical_sides`, the default) against the windows
   rounded up to 64 cells and point capacities of `capacity_bucket` (the former rule, which
   compiles once per new size). Runs alternate A B A B; the median of the per-pair ratios.
2. First runs: a fresh `XDG_CACHE_HOME`, `gfjax warmup` (timed), then per method and file
   two whole `gfjax filter` processes; the first against the second (same run); with
   `--pysmrf-file`, SMRF's first process there against `pysmrf.classify(windows=18)`'s call
   (the `.[bench]` extra); with `--api-file`, `gfjax.smrf.filter`'s first and second call in
   one fresh Python process, once with `gfjax.smrf` imported by the first call, once
   imported before it, and once with its programs loaded before it (`gfjax.smrf.warm()`).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gfjax.bench.harness import Stopwatch  # noqa: E402


def _padding_cost(files: list[str], methods: list[str], runs: int) -> list[str]:
    import gfjax
    from gfjax import methods as registry
    from gfjax.tiling import buckets

    canonical = buckets.canonical_sides
    rows = ["| method | file | canonical s (median) | former s (median) | ratio canonical / former (median, min-max) |",
            "|---|---|---|---|---|"]
    for path in files:
        cloud = gfjax.read(path)
        for name in methods:
            module = registry.get(name)

            def once(sides) -> float:
                buckets.canonical_sides = sides
                try:
                    with Stopwatch() as watch:
                        module.filter(cloud)
                    return watch.wall_s
                finally:
                    buckets.canonical_sides = canonical

            former = lambda *a: None                    # noqa: E731 (batches(sides=None): the former rule)
            for sides in (canonical, former):          # compile both first
                once(sides)
            a, b = [], []
            for _ in range(runs):
                a.append(once(canonical))
                b.append(once(former))
            ratios = [x / y for x, y in zip(a, b)]
            rows.append(f"| {name} | {Path(path).name} | {statistics.median(a):.3f} | {statistics.median(b):.3f} | "
                        f"{statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f}) |")
            print(rows[-1], flush=True)
    return rows


def _wall(command: list[str], env: dict) -> float:
    with Stopwatch() as watch:
        subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return watch.wall_s


# The two programs below are fresh processes that time themselves with the plain clock and print
# the seconds: an import of the harness there would add to what they measure (the API program's
# first call imports what it needs) or to the peer's process.
_API = """
import sys, time
import gfjax
cloud = gfjax.read(sys.argv[1])
if sys.argv[2:] in (["imported"], ["loaded"]):
    import gfjax.smrf
if sys.argv[2:] == ["loaded"]:
    gfjax.smrf.warm()
times = []
for _ in range(2):
    start = time.perf_counter()
    gfjax.smrf.filter(cloud)
    times.append(time.perf_counter() - start)
print(*times)
"""

_PYSMRF = """
import sys, time, warnings
import numpy as np, laspy, pysmrf
las = laspy.read(sys.argv[1])
x, y, z = (np.asarray(a, np.float64) for a in (las.x, las.y, las.z))
warnings.simplefilter("ignore")
start = time.perf_counter()
pysmrf.classify(x, y, z, cellsize=1.0, windows=18, slope_threshold=0.15, elevation_threshold=0.5,
                elevation_scaler=1.25)
print(time.perf_counter() - start)
"""


def _python(script: str, path: str, env: dict, *args: str) -> list[float]:
    done = subprocess.run([sys.executable, "-c", script, path, *args], env=env, check=True, capture_output=True,
                          text=True)
    return [float(x) for x in done.stdout.split()]


def _first_runs(files: list[str], methods: list[str], api_file: str | None, pysmrf_file: str | None) -> list[str]:
    gfjax_bin = str(Path(sys.executable).parent / "gfjax")
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = {k: v for k, v in os.environ.items() if k not in ("GFJAX_CACHE", "GFJAX_EXPORT_CACHE",
                                                               "JAX_COMPILATION_CACHE_DIR")}
        env |= {"XDG_CACHE_HOME": cache}
        warm = _wall([gfjax_bin, "-q", "warmup"], env)
        rows = [f"`gfjax warmup` on empty caches: {warm:.0f} s.", "",
                "| method | file | first run s | second run s | first / second |", "|---|---|---|---|---|"]
        print(rows[0], flush=True)
        pysmrf_row = ""
        for name in filter(None, methods):
            for path in files:
                command = [gfjax_bin, "-q", "filter", path, "-o", str(Path(out) / "out.laz"), "--method", name,
                           "--force"]
                first, second = _wall(command, env), _wall(command, env)
                rows.append(f"| {name} | {Path(path).name} | {first:.2f} | {second:.2f} | {first / second:.2f} |")
                print(rows[-1], flush=True)
                if name == "smrf" and path == pysmrf_file:
                    peer = _python(_PYSMRF, path, env)[0]
                    pysmrf_row = (f"SMRF's first `gfjax filter` process on {Path(path).name}: {first:.2f} s, "
                                  f"{first / peer:.2f}x `pysmrf.classify(windows=18)`'s call ({peer:.2f} s, same run).")
        rows += ["", pysmrf_row] if pysmrf_row else []
        if api_file:
            first, second = _python(_API, api_file, env)
            rows += ["", f"Python API, a fresh process after the warmup: `gfjax.smrf.filter` on {Path(api_file).name} "
                     f"{first:.2f} s, its second call {second:.2f} s ({first / second:.2f}x)."]
            first, second = _python(_API, api_file, env, "imported")
            rows += [f"The same with `import gfjax.smrf` (JAX's import) before the first call: {first:.2f} s, "
                     f"its second call {second:.2f} s ({first / second:.2f}x)."]
            first, second = _python(_API, api_file, env, "loaded")
            rows += [f"The same with every canonical SMRF program loaded before the first call "
                     f"(`gfjax.smrf.warm()`, untimed): {first:.2f} s, its second call {second:.2f} s "
                     f"({first / second:.2f}x): the first call's cost beyond loading."]
            print(*rows[-3:], sep="\n", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--methods", default="smrf,pmf", help="methods of the padding comparison (default smrf,pmf; empty: skip it)")
    parser.add_argument("--first-run-methods", default="smrf,pmf,dmf,csf,masf,sparsegf")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--api-file", help="a file for the Python API's first and second call in a fresh process")
    parser.add_argument("--pysmrf-file", help="one of FILES: SMRF's first process against pysmrf's call on it")
    parser.add_argument("-o", "--output", required=True)
    args = parser.parse_args()
    os.environ["GFJAX_CACHE"] = "0"           # this process: plain jit, compiled once per shape in memory
    padding = _padding_cost(args.files, args.methods.split(","), args.runs) if args.methods else ["(not run)"]
    first = _first_runs(args.files, args.first_run_methods.split(","), args.api_file, args.pysmrf_file)
    text = ["# Canonical shapes and `gfjax warmup`", "",
            f"Command: `{' '.join([Path(sys.executable).name, *sys.argv])}` "
            f"({os.cpu_count()} cores, {time.strftime('%Y-%m-%d')}).", "",
            "## Padding cost (warm programs, one process)", "", *padding, "",
            "## First run after `make demo`'s warmup (whole processes)", "", *first, ""]
    Path(args.output).write_text("\n".join(text))
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
