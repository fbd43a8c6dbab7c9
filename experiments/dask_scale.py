"""Scale-out: a 30 M-point survey filtered by `gfjax filter --workers N` (a local Dask cluster).

    nice .venv/bin/python experiments/dask_scale.py [--files 36] [--method smrf]

The survey is `--files` copies of `bcts_2` (`survey_scale.write_survey`: 824 k points each,
36 copies = 29.7 M points). Each `gfjax filter FILES -o DIR` process runs whole, in one
process and with `--workers 1` and `--workers 2`, after untimed runs on 4 files that fill the
persistent program caches; a poller reads the resident memory of the command and of each of
its worker processes every 0.2 s (psutil), so the table gives each one's peak.

Then the pieces of a larger estimate, measured here in one process: the index's and the
writer's rates (points/s), one tile's filtering (a sample of the survey's tiles), and Dask's
cost per task (no-op tasks on a 2-worker cluster).
Writes `experiments/results/dask_scale.md` and `.json`.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import numpy as np
import psutil
from survey_scale import GFJAX, ROOT, write_survey

from gfjax.bench.harness import Stopwatch

RESULTS = ROOT / "experiments" / "results"


def run(paths: list[Path], out: Path, method: str, extra: tuple[str, ...]) -> dict:
    """One `gfjax filter` process: wall time [s], its peak RSS and each worker's [bytes]."""
    out.mkdir()
    argv = [*GFJAX, "-q", "filter", *map(str, paths), "-o", str(out), "--method", method, *extra]
    peaks: dict[int, int] = {}
    watch = Stopwatch()
    child = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.DEVNULL)
    root = psutil.Process(child.pid)
    stop = threading.Event()

    def poll():
        while not stop.is_set():
            try:
                for p in [root, *root.children(recursive=True)]:
                    try:
                        peaks[p.pid] = max(peaks.get(p.pid, 0), p.memory_info().rss)
                    except psutil.Error:
                        pass
            except psutil.Error:
                return
            stop.wait(0.2)

    poller = threading.Thread(target=poll, daemon=True)
    poller.start()
    code = child.wait()
    wall = watch.stop().wall_s
    stop.set()
    poller.join()
    if code != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({code})")
    for f in out.iterdir():
        f.unlink()
    out.rmdir()
    workers = sorted((rss for pid, rss in peaks.items() if pid != child.pid and rss > 200 * 2**20), reverse=True)
    return {"wall_s": wall, "command_peak_rss_b": peaks.get(child.pid, 0), "worker_peak_rss_b": workers}


def serial_rates(paths: list[Path], method: str) -> dict:
    """The client's serial passes and one tile's cost, measured in this process."""
    from gfjax import methods, survey
    from gfjax.io import las as las_io
    from gfjax.survey.lattice import TileLabels, tile_labels

    module = methods.get(method)
    config = module.Config()
    out = {}
    with tempfile.TemporaryDirectory(prefix="gfjax_dask_") as folder:
        with Stopwatch() as watch:
            catalog = survey.index(paths, folder)
        out["index_s"] = watch.wall_s
        n_points = sum(e.n_points for e in catalog.entries)
        out["index_points_per_s"] = n_points / out["index_s"]

        def filter_fn(points, returns, core=None):
            return module.filter(points, config=config, returns=returns)

        lattice = methods.lattice(module, config)
        tiles = TileLabels(catalog, filter_fn, lattice, folder)
        keys = sorted(set().union(*tiles.keys))
        out["tiles"] = len(keys)
        sample = [keys[i] for i in np.linspace(0, len(keys) - 1, 8).round().astype(int)]
        tile_labels(catalog, filter_fn, lattice, sample[0])            # compiled (or loaded) before timing
        times, points = [], []
        for key in sample:
            with Stopwatch() as watch:
                parts = tile_labels(catalog, filter_fn, lattice, key)
            times.append(watch.wall_s)
            points.append(sum(len(index) for _, index, _ in parts))
        out["tile_s"] = float(np.median(times))
        out["tile_core_points"] = float(np.median(points))
        cloud = las_io.read(paths[0])
        with tempfile.TemporaryDirectory() as written:
            with Stopwatch() as watch:
                cloud = las_io.read(paths[0])
                las_io.write(cloud.with_ground(np.zeros(cloud.n_points, bool)), Path(written) / "a.laz")
            out["write_points_per_s"] = cloud.n_points / watch.wall_s
    return out


def task_overhead(n_tasks: int = 2000) -> float:
    """Seconds per no-op task, submitted and gathered on a local cluster of 2 workers."""
    from gfjax.survey import cluster

    with cluster.client(workers=2) as client:
        client.gather(client.map(int, range(100), pure=False))
        with Stopwatch() as watch:
            client.gather(client.map(int, range(n_tasks), pure=False))
        return watch.wall_s / n_tasks


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--files", type=int, default=36)
    parser.add_argument("--method", default="smrf")
    parser.add_argument("--out", type=Path, default=RESULTS / "dask_scale.md")
    parser.add_argument("--report-only", action="store_true", help="rewrite the report from the .json of a run")
    args = parser.parse_args()
    if args.report_only:
        saved = json.loads(args.out.with_suffix(".json").read_text())
        return report(saved["runs"], saved["rates"], args)
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax_dask_") as tmp:
        tmp = Path(tmp)
        paths = write_survey(tmp, args.files)
        import laspy

        n_points = sum(laspy.open(p).header.point_count for p in paths)
        modes = {"one process": (), "--workers 1": ("--workers", "1"), "--workers 2": ("--workers", "2")}
        for extra in modes.values():                          # untimed: fills the program caches
            run(paths[:4], tmp / "warm", args.method, extra)
        for name, extra in modes.items():
            row = run(paths, tmp / "out", args.method, extra) | {"run": name, "points": n_points}
            rows.append(row)
            print(f"{name}: {row['wall_s']:.1f} s, command {row['command_peak_rss_b'] / 2**30:.2f} GiB, workers "
                  f"{[round(r / 2**30, 2) for r in row['worker_peak_rss_b']]} GiB", flush=True)
        rates = serial_rates(paths, args.method)
    rates["task_overhead_s"] = task_overhead()
    print(rates, flush=True)
    args.out.with_suffix(".json").write_text(json.dumps({"runs": rows, "rates": rates}, indent=1))
    report(rows, rates, args)


def report(rows: list[dict], rates: dict, args) -> None:
    """The results file from the runs and the measured rates."""
    n_points = rows[0]["points"]
    by = {r["run"]: r for r in rows}
    speedup = by["--workers 1"]["wall_s"] / by["--workers 2"]["wall_s"]
    lines = ["# Scale-out: a survey on a local Dask cluster", "",
             f"Command: `nice .venv/bin/python experiments/dask_scale.py --files {args.files} --method {args.method}`  ",
             f"{args.files} copies of bcts_2, {n_points:,} points, {rates['tiles']} tiles of {args.method}'s lattice; "
             f"2-core CPU; load average at the end {' '.join(f'{x:.1f}' for x in os.getloadavg())}.", "",
             "| run | wall s | points/s | command peak RSS GiB | worker peak RSS GiB |",
             "| --- | ---: | ---: | ---: | --- |"]
    for r in rows:
        workers = ", ".join(f"{b / 2**30:.2f}" for b in r["worker_peak_rss_b"]) or "-"
        lines.append(f"| {r['run']} | {r['wall_s']:.1f} | {r['points'] / r['wall_s']:,.0f} | "
                     f"{r['command_peak_rss_b'] / 2**30:.2f} | {workers} |")
    lines += ["", f"- `--workers 2` is {speedup:.2f}x as fast as `--workers 1` (same run).",
              f"- One process's rates: the index reads {rates['index_points_per_s']:,.0f} points/s, the writer "
              f"(read, relabel, write LAZ) {rates['write_points_per_s']:,.0f} points/s.",
              f"- One tile on one process: median {rates['tile_s']:.2f} s for {rates['tile_core_points']:,.0f} core "
              f"points (8 tiles across the survey).",
              f"- Dask's cost per task here: {1e3 * rates['task_overhead_s']:.2f} ms (2,000 no-op tasks, 2 workers)."]
    tiles, workers = 10_000, 100
    compute = tiles / workers * rates["tile_s"]
    big_points = tiles * rates["tile_core_points"]
    index = big_points / rates["index_points_per_s"] / workers
    write = big_points / rates["write_points_per_s"] / workers
    scheduling = 3 * tiles * rates["task_overhead_s"]
    lines += ["", f"## Estimate: {tiles:,} such tiles ({big_points / 1e9:.1f} billion points) on {workers} workers", "",
              "On a cluster of other machines (`--scheduler`) every pass over the points is a task on the "
              "workers (a file's index, a tile, a file's copy); the command only schedules, and renames each "
              "finished copy into place.", "",
              f"- The index: {big_points / 1e9:.1f} billion points / {workers} workers at the rate above = "
              f"{index / 60:.0f} min.",
              f"- Tiles: {tiles:,} / {workers} x {rates['tile_s']:.2f} s = {compute / 60:.0f} min, "
              "if the workers read their windows as fast as here (a shared file system is slower).",
              f"- The copies: {write / 60:.0f} min at the writer's rate above, per worker.",
              f"- Scheduling: {3 * tiles:,} tasks x {1e3 * rates['task_overhead_s']:.2f} ms = {scheduling:.0f} s "
              "(a file's index and copy counted as one task per tile each), "
              "overlapped with the work.",
              f"- So about {(index + compute + write) / 60:.0f} min, if the shared storage keeps up with "
              f"{workers} workers reading and writing at once (this machine's disk was not the bound here)."]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main())
