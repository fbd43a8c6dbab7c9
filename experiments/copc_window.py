"""COPC input: what a tile window's query reads, against a full read, on a real sample.

    nice .venv/bin/python experiments/copc_window.py [--tile 100] [--buffer 20]

`bcts_2` (../shared/data/lasR_bcts) is written as COPC by copc-lib (`tests/io/copc_writer.py`:
octree depth 5, nodes of up to 4,096 points, as COPC builders fill it) and as LAS from the same
points. Over SMRF's lattice of `--tile` m tiles with `--buffer` m buffers, each tile's window
is queried (`gfjax.io.copc.Reader.within`): the table gives the points decompressed (the nodes
that meet the window) against the window's points and the file's, and the query's time against
a full read. Then the two files are filtered as a one-file survey with those tiles
(`gfjax.survey.filtered`: the COPC file's tile windows come from queries, the LAS file's from
its store) and their labels compared. Writes `experiments/results/copc_window.md`.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "io")]
from copc_writer import write_copc  # noqa: E402
from survey_scale import RESULTS, SOURCE  # noqa: E402

from experiments.common import median_time  # noqa: E402
from gfjax.bench.harness import Stopwatch  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tile", type=float, default=100.0)
    parser.add_argument("--buffer", type=float, default=20.0)
    parser.add_argument("--out", type=Path, default=RESULTS / "copc_window.md")
    args = parser.parse_args()

    from gfjax import smrf, survey
    from gfjax.io import copc
    from gfjax.io.cloud import Frame
    from gfjax.survey.halo import tiles_region
    from gfjax.tiling.tiles import Tiling

    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax_copc_") as tmp:
        tmp = Path(tmp)
        written = write_copc(laspy.read(SOURCE), tmp / "bcts_2.copc.laz", depth=5, capacity=4096)
        written.write(tmp / "bcts_2.las")
        n = len(written.points)
        full_s = median_time(lambda: laspy.read(tmp / "bcts_2.copc.laz"), repeats=3)
        tiling = Tiling(tile_size_m=args.tile, buffer_m=args.buffer)
        lattice = tiling.lattice(smrf.Config().cell_m)
        xy = np.column_stack([written.x, written.y])
        frame = Frame(np.array([*xy.min(axis=0), 0.0]), xy.max(axis=0))
        last = np.floor((xy.max(axis=0) - xy.min(axis=0)) / args.tile).astype(int)
        with copc.Reader(tmp / "bcts_2.copc.laz") as reader:
            for col in range(last[0] + 1):
                for row in range(last[1] + 1):
                    lo, hi = tiles_region(np.array([col, row]), np.array([col, row]), frame, lattice)
                    before = reader.read_points
                    with Stopwatch() as watch:
                        index, _ = reader.within(lo, hi)
                    rows.append({"tile": (col, row), "window": len(index), "read": reader.read_points - before,
                                 "s": watch.wall_s})

        labels = {}
        for name in ("bcts_2.copc.laz", "bcts_2.las"):
            folder = tmp / f"stores_{name}"
            folder.mkdir()
            (_, result), = survey.filtered([tmp / name], smrf, folder, tiling=tiling)
            labels[name] = np.asarray(result.ground)
    same = np.array_equal(labels["bcts_2.copc.laz"], labels["bcts_2.las"])

    read, window = sum(r["read"] for r in rows), sum(r["window"] for r in rows)
    lines = ["# COPC: a tile window's query against a full read", "",
             f"Command: `nice .venv/bin/python experiments/copc_window.py --tile {args.tile:g} "
             f"--buffer {args.buffer:g}`  ",
             f"bcts_2 as COPC ({n:,} points; octree depth 5, nodes of up to 4,096 points, written by copc-lib); "
             f"SMRF tiles of {args.tile:g} m with {args.buffer:g} m buffers: {len(rows)} windows.", "",
             "| tile | points in the window | points decompressed | share of the file | query s |",
             "| --- | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['tile']} | {r['window']:,} | {r['read']:,} | {100 * r['read'] / n:.1f} % | {r['s']:.3f} |")
    lines += ["",
              f"- Over the {len(rows)} windows the queries decompressed {read:,} points for {window:,} window points: "
              f"{read / window:.2f} per point wanted, against {len(rows) * n / window:.2f} if each window read the "
              f"whole file ({100 * read / (len(rows) * n):.1f} % of those reads).",
              f"- A full read of the file takes {full_s:.2f} s (median of 3); a window's query "
              f"{np.median([r['s'] for r in rows]):.3f} s (median).",
              f"- Labels of the COPC file filtered as a survey (windows from queries) against its LAS copy "
              f"(windows from the store): {'identical' if same else 'DIFFERENT'} "
              f"({int(np.sum(labels['bcts_2.copc.laz'] != labels['bcts_2.las']))} of {n:,} differ)."]
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
