"""Scale: memory and throughput of a whole survey against its size.

    nice .venv/bin/python experiments/survey_scale.py [--methods smrf,dmf] [--tiles 4,12,42]

A synthetic survey of `n` files is written as copies of the forest tile `bcts_2`
(../shared/data/lasR_bcts, 823,945 points over 193 x 300 m) laid side by side on a grid of
200 x 300 m cells, each copy shifted by whole metres (every point and attribute kept). For each method and size, one `gfjax filter FILES... -o DIR` process
filters the files as a survey (`gfjax.survey.Runner`: a tiled method runs each tile of the
survey's lattice once, any other method each file with its neighbours' halo) and,
for comparison, one process with `--independent` (today's in-memory path, each file alone).
The table gives each process's peak resident memory (`ru_maxrss` of the child), its
throughput (points of the survey / wall time of the whole process) and its CPU time (user +
system of the child, every thread: on a machine shared with other jobs the wall time follows
their load, the CPU time much less), after untimed runs that compile every window shape met. The seam test lives in
`experiments/survey_seams.py`. Writes `experiments/results/survey_scale.md` (and `.json`, and
`survey_scale.png`: peak memory against survey size).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from gfjax.bench.harness import Stopwatch  # noqa: E402

DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
SOURCE = DATA / "lasR_bcts" / "bcts_2.laz"
CELL_M = (200.0, 300.0)          # the grid the copies are laid on [m]; bcts_2 spans 193 x 300 m
RESULTS = ROOT / "experiments" / "results"
GFJAX = [sys.executable, "-m", "gfjax.cli.main"]


def write_survey(folder: Path, n_files: int) -> list[Path]:
    """`n_files` copies of `SOURCE` on a near-square grid of `CELL_M` cells, in `folder`."""
    las = laspy.read(SOURCE)
    x, y = np.array(las.x), np.array(las.y)
    columns = math.ceil(math.sqrt(n_files))
    paths = []
    for k in range(n_files):
        row, col = divmod(k, columns)
        # whole metres on a 0.01 m scale: the stored integers shift, every coordinate exactly
        las.x, las.y = x + col * CELL_M[0], y + row * CELL_M[1]
        path = folder / f"tile_{row:02d}_{col:02d}.laz"
        las.write(path)
        paths.append(path)
    return paths


def write_one_file(folder: Path, n_copies: int) -> Path:
    """The same `n_copies` as `write_survey`, in one file."""
    las = laspy.read(SOURCE)
    columns = math.ceil(math.sqrt(n_copies))
    step = np.round(np.asarray(CELL_M) / np.asarray(las.header.scales[:2])).astype(np.int64)
    parts = []
    for k in range(n_copies):
        row, col = divmod(k, columns)
        part = las.points.array.copy()
        part["X"] += col * step[0]
        part["Y"] += row * step[1]
        parts.append(part)
    las.points = laspy.ScaleAwarePointRecord(np.concatenate(parts), las.header.point_format, las.header.scales,
                                             las.header.offsets)
    path = folder / f"one_{n_copies}.laz"
    las.write(path)
    return path


def run(paths: list[Path], out: Path, method: str, independent: bool, *, extra: tuple[str, ...] = ()) -> dict:
    """One whole `gfjax filter` process: wall time [s], CPU time [s] and peak RSS [bytes]."""
    out.mkdir()
    argv = [*GFJAX, "-q", "filter", *map(str, paths), "-o", str(out), "--method", method, *extra]
    if independent:
        argv.append("--independent")
    with Stopwatch() as watch:
        child = subprocess.Popen(argv, cwd=ROOT)
        _, status, usage = os.wait4(child.pid, 0)
    wall = watch.wall_s
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({os.waitstatus_to_exitcode(status)})")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_rss_b": usage.ru_maxrss * 1024}


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for method in sorted({r["method"] for r in rows}):
        for mode, style in (("survey", "o-"), ("independent", "s--")):
            sel = sorted((r for r in rows if r["method"] == method and r["mode"] == mode), key=lambda r: r["points"])
            if sel:
                ax.plot([r["points"] / 1e6 for r in sel], [r["peak_rss_b"] / 2**30 for r in sel], style,
                        label=f"{method} {mode}")
    ax.axhline(2.0, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("survey size [million points]")
    ax.set_ylabel("peak resident memory [GiB]")
    ax.set_ylim(bottom=0)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="smrf,dmf")
    parser.add_argument("--tiles", default="4,12,42", help="survey sizes in files (copies of bcts_2)")
    parser.add_argument("--independent-tiles", default="4,42",
                        help="the sizes also filtered one file at a time (--independent)")
    parser.add_argument("--one-file", default="12,42",
                        help="copies merged into one file, filtered with SMRF out of core (and in memory "
                             "while it fits the budget)")
    parser.add_argument("--out", type=Path, default=RESULTS / "survey_scale.md")
    args = parser.parse_args()
    sizes = [int(s) for s in args.tiles.split(",")]
    alone = {int(s) for s in args.independent_tiles.split(",") if s}
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax_scale_") as tmp:
        tmp = Path(tmp)
        all_paths = write_survey(tmp, max(sizes))
        for method in args.methods.split(","):
            # untimed: compiles every window shape the timed runs meet (a partly and a fully
            # covered tile: 4 and 12 files), so no row pays for compiling
            for n, mode in ((4, "survey"), (12, "survey"), (4, "independent")):
                out = tmp / f"warm_{method}_{n}_{mode}"
                run(all_paths[:min(n, len(all_paths))], out, method, mode == "independent")
                for f in out.iterdir():
                    f.unlink()
            for n in sizes:
                paths = all_paths[:n]
                points = n * laspy.open(SOURCE).header.point_count
                for mode in ("survey", "independent"):
                    if mode == "independent" and n not in alone:
                        continue
                    row = run(paths, tmp / f"out_{method}_{n}_{mode}", method, mode == "independent")
                    row |= {"method": method, "files": n, "points": points, "mode": mode,
                            "points_per_s": points / row["wall_s"]}
                    rows.append(row)
                    print(f"{method} {mode} {n} files {points:,} points: {row['wall_s']:.1f} s, "
                          f"CPU {row['cpu_s']:.1f} s, {row['peak_rss_b'] / 2**30:.2f} GiB", flush=True)
                    for f in (tmp / f"out_{method}_{n}_{mode}").iterdir():
                        f.unlink()

        for n in [int(v) for v in args.one_file.split(",") if v]:
            path = write_one_file(tmp, n)
            points = n * laspy.open(SOURCE).header.point_count
            for mode, extra in (("one file, out of core", ("--out-of-core",)), ("one file, in memory", ())):
                if not extra and points * 700 > 12 * 2**30:
                    continue                  # over this machine's default budget: it would go out of core
                out = tmp / f"out_one_{n}_{len(extra)}"
                row = run([path], out, "smrf", False, extra=extra)
                row |= {"method": "smrf", "files": 1, "points": points, "mode": mode,
                        "points_per_s": points / row["wall_s"]}
                rows.append(row)
                print(f"smrf {mode} {points:,} points: {row['wall_s']:.1f} s, {row['peak_rss_b'] / 2**30:.2f} GiB",
                      flush=True)
                for f in out.iterdir():
                    f.unlink()
            path.unlink()

    lines = ["# Survey scale: peak memory and throughput against survey size", "",
             f"Command: `nice .venv/bin/python experiments/survey_scale.py --methods {args.methods} "
             f"--tiles {args.tiles} --independent-tiles {args.independent_tiles} --one-file {args.one_file}`  ",
             f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU.", "",
             "| method | files | points | run | wall s | points/s | CPU s | peak RSS GiB |",
             "| --- | ---: | ---: | --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['files']} | {r['points']:,} | {r['mode']} | {r['wall_s']:.1f} | "
                     f"{r['points_per_s']:,.0f} | {r['cpu_s']:.1f} | {r['peak_rss_b'] / 2**30:.2f} |")
    lines.append("")
    for method in args.methods.split(","):
        mine = {(r["files"], r["mode"]): r for r in rows if r["method"] == method}
        small, large = min(sizes), max(sizes)
        if (small, "survey") in mine and (large, "survey") in mine:
            ratio = mine[large, "survey"]["peak_rss_b"] / mine[small, "survey"]["peak_rss_b"]
            lines.append(f"- {method}: peak memory on {large} files is {ratio:.2f}x that on {small}.")
        for n in sorted(alone):
            if (n, "survey") in mine and (n, "independent") in mine:
                share = mine[n, "survey"]["points_per_s"] / mine[n, "independent"]["points_per_s"]
                cpu = mine[n, "independent"]["cpu_s"] / mine[n, "survey"]["cpu_s"]
                lines.append(f"- {method}: survey throughput on {n} files is {100 * share:.0f} % of the "
                             f"files filtered one at a time ({100 * cpu:.0f} % by CPU time).")
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    plot([r for r in rows if r["files"] > 1 or r["mode"] == "survey"], args.out.with_suffix(".png"))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
