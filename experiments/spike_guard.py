"""The spike guard's neighbour queries skipped where no median can unmake a point: same labels, time.

    nice .venv/bin/python experiments/spike_guard.py

For every labelled file of `../shared/data` (`experiments.common.LABELLED`) and two sets of
ground labels, the file's reference ground (ASPRS class 2) and SMRF's own labels
(`gfjax.smrf.filter` at its defaults, before any guard), `gfjax.spikes.despike` runs as it
ships (`_unsure` leaves out the points whose 5 x 5 cells prove them no spike) and with every
ground point queried (`_unsure` replaced by every row: the guard as it was). The labels must be
identical (the script stops otherwise); the table gives the share of ground points still
queried and each run's time (median of 3 warm calls). Writes
`experiments/results/spike_guard.md`.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import gfjax  # noqa: E402
from experiments.common import RESULTS, labelled, median_time, write_markdown  # noqa: E402
from gfjax import spikes  # noqa: E402


def every_row(xy, z, **_):
    return np.arange(len(xy))


def main() -> None:
    lines = ["# The spike guard: neighbour queries only where a median could unmake a point", "",
             "Command: `nice .venv/bin/python experiments/spike_guard.py`. `despike` as it ships against every",
             "ground point queried (the guard before), medians of 3 warm calls; labels identical on every row.", "",
             "| file | labels | ground points | queried | every point s | shipped s | ratio |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    total = [0.0, 0.0]
    shipped = spikes._unsure
    for item in labelled():
        cloud = gfjax.read(item.file)
        xyz = np.asarray(cloud.xyz_m)
        for name, ground in (("reference", np.asarray(cloud.classification) == 2),
                             ("SMRF", np.asarray(gfjax.smrf.filter(cloud).ground, bool))):
            index = np.flatnonzero(ground)
            queried = 1.0
            if index.size > spikes.NEIGHBOURS:
                xy = xyz[index, :2] - xyz[index, :2].min(axis=0)
                queried = shipped(xy, xyz[index, 2], threshold_m=spikes.THRESHOLD_M, slope=spikes.SLOPE,
                                  k=spikes.NEIGHBOURS).size / index.size
            now = spikes.despike(xyz, ground)
            now_s = median_time(spikes.despike, xyz, ground, repeats=3)
            spikes._unsure = every_row
            try:
                before = spikes.despike(xyz, ground)
                before_s = median_time(spikes.despike, xyz, ground, repeats=3)
            finally:
                spikes._unsure = shipped
            if not np.array_equal(now, before):
                raise SystemExit(f"{item.name} ({name}): {int((now != before).sum())} labels differ")
            total[0] += before_s
            total[1] += now_s
            lines.append(f"| {item.name} | {name} | {index.size:,} | {queried:.0%} | {before_s:.3f} | {now_s:.3f} | "
                         f"{now_s / before_s:.2f} |")
            print(lines[-1], flush=True)
    lines += ["", f"All files and labels: {total[1]:.2f} s against {total[0]:.2f} s ({total[1] / total[0]:.2f}), "
              "the same labels."]
    write_markdown(RESULTS / "spike_guard.md", lines)


if __name__ == "__main__":
    main()
