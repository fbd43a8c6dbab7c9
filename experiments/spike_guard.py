"""The spike guard's neighbour queries skipped where no median can unmake a point, and its tree
split at sliding midpoints: same labels, time.

    nice .venv/bin/python experiments/spike_guard.py

For every labelled file of `../shared/data` (`experiments.common.LABELLED`) and two sets of
ground labels, the file's reference ground (ASPRS class 2) and SMRF's own labels
(`gfjax.smrf.filter` at its defaults, before any guard), `gfjax.spikes.despike` runs as it
ships (`_unsure` leaves out the points whose 5 x 5 cells prove them no spike) and with every
ground point queried (`_unsure` replaced by every row: the guard as it was), and with its KD-tree
split at medians (scipy's default) instead of sliding midpoints. The labels must be identical
(the script stops otherwise); the table gives the share of ground points still queried and each
run's time (median of 3 warm calls). Writes `experiments/results/spike_guard.md`.
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


def median_split_tree(xy):
    from scipy.spatial import cKDTree

    return cKDTree(xy)


def timed(variant: dict, xyz: np.ndarray, ground: np.ndarray) -> tuple[np.ndarray, float]:
    """`despike`'s labels and median time with `spikes`' functions replaced by `variant`."""
    shipped = {name: getattr(spikes, name) for name in variant}
    for name, function in variant.items():
        setattr(spikes, name, function)
    try:
        return spikes.despike(xyz, ground), median_time(spikes.despike, xyz, ground, repeats=3)
    finally:
        for name, function in shipped.items():
            setattr(spikes, name, function)


def main() -> None:
    lines = ["# The spike guard: neighbour queries only where a median could unmake a point", "",
             "Command: `nice .venv/bin/python experiments/spike_guard.py`. `despike` as it ships against every",
             "ground point queried (the guard before) and against its tree split at medians, medians of 3",
             "warm calls; labels identical on every row.", "",
             "| file | labels | ground points | queried | every point s | median-split tree s | shipped s | ratio |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    total = [0.0, 0.0, 0.0]
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
            now, now_s = timed({}, xyz, ground)
            times = []
            for label, variant in (("every point queried", {"_unsure": every_row}),
                                   ("median-split tree", {"_tree": median_split_tree})):
                before, seconds = timed(variant, xyz, ground)
                if not np.array_equal(now, before):
                    raise SystemExit(f"{item.name} ({name}), {label}: {int((now != before).sum())} labels differ")
                times.append(seconds)
            every_s, median_s = times
            for j, seconds in enumerate((every_s, now_s, median_s)):
                total[j] += seconds
            lines.append(f"| {item.name} | {name} | {index.size:,} | {queried:.0%} | {every_s:.3f} | {median_s:.3f} | "
                         f"{now_s:.3f} | {now_s / every_s:.2f} |")
            print(lines[-1], flush=True)
    lines += ["", f"All files and labels: {total[1]:.2f} s against {total[0]:.2f} s with every point queried "
              f"({total[1] / total[0]:.2f}) and {total[2]:.2f} s with the median-split tree "
              f"({total[1] / total[2]:.2f}), the same labels."]
    write_markdown(RESULTS / "spike_guard.md", lines)


if __name__ == "__main__":
    main()
