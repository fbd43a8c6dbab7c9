"""The tile size's trade-off on a survey: throughput against flat memory.

    nice .venv/bin/python experiments/survey_tradeoff.py [--methods smrf] [--tile-sizes 250,500,1000]

The synthetic survey of `experiments/survey_scale.py` (copies of the forest tile bcts_2, 823,945
points over 193 x 300 m each), filtered as a survey of 4 and of 42 files with each `--tile-size`
(the default 50 m buffer), and the 42 files one at a time (`--independent`, no buffer) for
the throughput reference. A tiled method's labels do not depend on the tile size (the buffer
gives every tile its context); what changes is how many buffer points each core carries,
`((tile + 2 buffer) / tile)^2` times its own, and how large the largest window is, which sets
the peak memory. Untimed runs first compile every window shape met. Writes
`experiments/results/survey_tradeoff.md` (and `.json`).
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
from pathlib import Path

import laspy
from survey_scale import RESULTS, SOURCE, run, write_survey


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="smrf")
    parser.add_argument("--tile-sizes", default="250,500,1000")
    parser.add_argument("--small", type=int, default=4, help="files of the small survey")
    parser.add_argument("--large", type=int, default=42, help="files of the large survey")
    parser.add_argument("--out", type=Path, default=RESULTS / "survey_tradeoff.md")
    args = parser.parse_args()
    sizes = [float(s) for s in args.tile_sizes.split(",")]
    per_file = laspy.open(SOURCE).header.point_count
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax_tradeoff_") as tmp:
        tmp = Path(tmp)
        paths = write_survey(tmp, args.large)
        counter = iter(range(10**6))

        def once(n: int, method: str, tile_m: float | None, *, timed: bool) -> dict | None:
            out = tmp / f"out_{next(counter)}"
            extra = () if tile_m is None else ("--tile-size", f"{tile_m:g}")
            row = run(paths[:n], out, method, tile_m is None, extra=extra)
            for f in out.iterdir():
                f.unlink()
            if not timed:
                return None
            row |= {"method": method, "files": n, "points": n * per_file,
                    "tile_m": tile_m, "points_per_s": n * per_file / row["wall_s"]}
            label = "one at a time" if tile_m is None else f"survey, {tile_m:g} m tiles"
            print(f"{method} {label}, {n} files: {row['wall_s']:.1f} s, {row['peak_rss_b'] / 2**30:.2f} GiB",
                  flush=True)
            return row

        for method in args.methods.split(","):
            once(args.small, method, None, timed=False)
            rows.append(once(args.large, method, None, timed=True))
            for tile_m in sizes:
                for n in (args.small, 12):           # untimed: a partly and a fully covered tile
                    once(n, method, tile_m, timed=False)
                for n in (args.small, args.large):
                    rows.append(once(n, method, tile_m, timed=True))

    lines = ["# Survey tile size: throughput against flat memory", "",
             f"Command: `nice .venv/bin/python experiments/survey_tradeoff.py --methods {args.methods} "
             f"--tile-sizes {args.tile_sizes}`  ",
             f"Load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}; 2-core CPU. "
             "Buffer 50 m. Throughput share: the survey's points per second against the same files "
             f"filtered one at a time (`--independent`); memory ratio: peak RSS on {args.large} files "
             f"against {args.small}.", "",
             "| method | tile m | window area / core area | survey s | share of one at a time | "
             f"peak GiB, {args.small} files | peak GiB, {args.large} files | memory ratio |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for method in args.methods.split(","):
        alone = next(r for r in rows if r["method"] == method and r["tile_m"] is None)
        for tile_m in sizes:
            small, large = (next(r for r in rows if r["method"] == method and r["tile_m"] == tile_m
                                 and r["files"] == n) for n in (args.small, args.large))
            overhead = ((tile_m + 2 * 50.0) / tile_m) ** 2
            lines.append(f"| {method} | {tile_m:g} | {overhead:.2f} | {large['wall_s']:.1f} | "
                         f"{100 * large['points_per_s'] / alone['points_per_s']:.0f} % | "
                         f"{small['peak_rss_b'] / 2**30:.2f} | {large['peak_rss_b'] / 2**30:.2f} | "
                         f"{large['peak_rss_b'] / small['peak_rss_b']:.2f}x |")
        lines.append(f"| {method} | one at a time | 1.00 | {alone['wall_s']:.1f} | 100 % | | "
                     f"{alone['peak_rss_b'] / 2**30:.2f} | |")
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
