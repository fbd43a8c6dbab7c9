"""SparseGF partition and context compression on real clouds: patch counts and sizes, coverage
by the central regions, and throughput.

For each file: `gfjax.sparsegf.partition` (cylinders of R_oo = 150 m on a 50 m grid; host
numpy), the patch-frame gather (`PatchBatch.local_xyz`, host numpy), and `compress`
(Eqs. 1-3, R_in = 25 sqrt(2) m, R_oc = 44 m) jitted and vmapped over each capacity bucket
(compile time apart; timed after one warm-up call, `block_until_ready`); each time is
the fastest of `--repeat` (3) runs. The number of
central regions holding each point is counted with `soft_vote` (its vote count). Labelled
files also get the HAG targets (`hag_targets`, host scipy) timed and their bin shares.

Usage:
  nice .venv/bin/python experiments/sparsegf_partition.py [FILES...]
Default files: ../shared/data/lasR_bcts/bcts_2.laz and isprs_filtertest/sites/CSite4_orig-utm.laz.
Results: experiments/results/sparsegf_partition.md (one JSON line per file on stdout).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import gfjax
from gfjax import sparsegf
from gfjax.bench.harness import Stopwatch, time_call

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
DEFAULT_FILES = [DATA / "lasR_bcts" / "bcts_2.laz", DATA / "isprs_filtertest" / "sites" / "CSite4_orig-utm.laz"]
RESULTS = ROOT / "experiments" / "results"


def _compress_central(xyz, valid):
    """One patch in its own frame (axis at the origin): compressed xyz and central mask."""
    return sparsegf.compress(xyz, jnp.zeros(2, jnp.float32), valid=valid)


COMPRESS_BATCH = jax.jit(jax.vmap(_compress_central))


def _best_of(repeat: int, fn):
    """(fastest wall time of `repeat` calls [s], result of the last call)."""
    timing, result = time_call(fn, repeat=repeat, warmup=0)
    return timing.min_s, result


def run_file(path: Path, *, repeat: int = 3) -> dict:
    cloud = gfjax.read(path)
    xyz = cloud.xyz_m
    n = len(xyz)

    t_partition, part = _best_of(repeat, lambda: sparsegf.partition(xyz))

    def gather():
        arrays = ([jnp.asarray(b.local_xyz(xyz)) for b in part.batches], [jnp.asarray(b.valid) for b in part.batches])
        return jax.block_until_ready(arrays)

    t_gather, arrays = _best_of(repeat, gather)
    local, valid = arrays

    t_compile = 0.0
    for x, v in zip(local, valid):
        with Stopwatch() as watch:
            COMPRESS_BATCH.lower(x, v).compile()
        t_compile += watch.wall_s
        jax.block_until_ready(COMPRESS_BATCH(x, v))                # warm-up
    t_compress, outs = _best_of(repeat, lambda local=local, valid=valid: jax.block_until_ready(
        [COMPRESS_BATCH(x, v) for x, v in zip(local, valid)]))

    count = np.zeros(n, np.int64)
    central_per_patch = []
    for batch, out in zip(part.batches, outs):
        vote = sparsegf.soft_vote(jnp.asarray(batch.index), jnp.ones(batch.index.shape, jnp.float32), n,
                                  mask=out.central)
        count += np.asarray(vote.count)
        central_per_patch.extend(np.asarray(out.central).sum(axis=1).tolist())
    del outs, local, valid

    members = int(part.n_points.sum())
    slots = sum(int(b.index.size) for b in part.batches)
    row = dict(
        file=str(path.relative_to(DATA)) if path.is_relative_to(DATA) else str(path),
        n_points=n,
        bbox_m=[round(float(v), 1) for v in np.ptp(xyz[:, :2], axis=0)],
        n_patches=len(part.centers_m),
        points_per_patch=dict(min=int(part.n_points.min()), median=float(np.median(part.n_points)),
                              max=int(part.n_points.max())),
        central_per_patch=dict(min=int(min(central_per_patch)), median=float(np.median(central_per_patch)),
                               max=int(max(central_per_patch))),
        buckets=[[int(b.index.shape[0]), b.capacity] for b in part.batches],
        members_total=members,
        padding_share=1.0 - members / slots,
        covered_share={"0": float(np.mean(count == 0)), "1": float(np.mean(count == 1)),
                       "2": float(np.mean(count == 2)), "3+": float(np.mean(count >= 3))},
        max_cover=int(count.max()),
        t_partition_s=t_partition, t_gather_s=t_gather, t_compile_s=t_compile, t_compress_s=t_compress,
        points_per_s_total=n / (t_partition + t_gather + t_compress),
        members_per_s_compress=members / t_compress,
    )
    cls = cloud.classification
    if np.any(cls == 2):
        with Stopwatch() as watch:
            hag = sparsegf.hag_targets(xyz, cls)
        row["t_hag_s"] = watch.wall_s
        row["hag_bin_share"] = (np.bincount(hag.bins, minlength=sparsegf.N_HAG_BINS) / n).tolist()
    return row


def to_markdown(rows: list[dict], command: str, env: str) -> str:
    lines = ["# SparseGF partition and context compression", "",
             f"Command: `{command}`", "", f"Environment: {env}", "",
             "Partition: cylinders of R_oo = 150 m on a 50 m grid of axes (patches whose central "
             "region is empty dropped); compression R_in = 25 sqrt(2) m, R_oc = 44 m. Times are the fastest "
             "of 3 runs (compress after a warm-up); `compress` compile time is listed apart and excluded from "
             "points/s. Total points/s = cloud points / (partition + gather + compress).", "",
             "| file | points | bbox x, y (m) | patches | points/patch min / median / max | "
             "central pts/patch min / median / max | buckets (patches x capacity) | padding |",
             "| --- | ---: | --- | ---: | --- | --- | --- | ---: |"]
    for r in rows:
        p, c = r["points_per_patch"], r["central_per_patch"]
        buckets = ", ".join(f"{b} x {cap:,}" for b, cap in r["buckets"])
        lines.append(f"| {r['file']} | {r['n_points']:,} | {r['bbox_m'][0]} x {r['bbox_m'][1]} | "
                     f"{r['n_patches']} | {p['min']:,} / {p['median']:,.0f} / {p['max']:,} | "
                     f"{c['min']:,} / {c['median']:,.0f} / {c['max']:,} | {buckets} | "
                     f"{100 * r['padding_share']:.1f} % |")
    lines += ["", "Share of points by the number of central regions that hold them "
              "(every point must be in at least one). On a square grid of step s with "
              "R_in = s sqrt(2) / 2 the four central discs around a cell corner meet only at the "
              "corner, so 3+ happens only within `CENTRAL_TOL_M` (0.1 mm) of a corner:", "",
              "| file | 0 | 1 | 2 | 3+ | max |", "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        s = r["covered_share"]
        lines.append(f"| {r['file']} | {100 * s['0']:.4f} % | {100 * s['1']:.2f} % | {100 * s['2']:.2f} % | "
                     f"{100 * s['3+']:.4f} % | {r['max_cover']} |")
    lines += ["", "| file | partition (s) | gather (s) | compress compile (s) | compress (s) | "
              "compress (patch points/s) | total (cloud points/s) |",
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['file']} | {r['t_partition_s']:.2f} | {r['t_gather_s']:.2f} | "
                     f"{r['t_compile_s']:.2f} | {r['t_compress_s']:.3f} | {r['members_per_s_compress']:,.0f} | "
                     f"{r['points_per_s_total']:,.0f} |")
    labelled = [r for r in rows if "t_hag_s" in r]
    if labelled:
        lines += ["", "HAG targets (TIN of the class-2 points; bins 0: ground, 1: <= 0.2 m, 2: <= 0.5 m, "
                  "3: <= 1 m, 4: <= 3 m, 5: > 3 m):", "",
                  "| file | hag_targets (s) | bin 0 | 1 | 2 | 3 | 4 | 5 |",
                  "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for r in labelled:
            shares = " | ".join(f"{100 * s:.1f} %" for s in r["hag_bin_share"])
            lines.append(f"| {r['file']} | {r['t_hag_s']:.2f} | {shares} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, default=DEFAULT_FILES)
    parser.add_argument("--repeat", type=int, default=3, help="report the fastest of this many runs")
    args = parser.parse_args(argv)
    rows = []
    for path in args.files:
        row = run_file(path, repeat=args.repeat)
        print(json.dumps(row), flush=True)
        rows.append(row)
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    env = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPU cores, jax {jax.__version__} on "
           f"{jax.devices()[0].platform} ({jax.devices()[0].device_kind}), float32; machine shared with "
           f"other jobs, load average {load} at the end of the run, so times are indicative")
    command = "nice .venv/bin/python experiments/sparsegf_partition.py" + (
        "" if args.files == DEFAULT_FILES else " " + " ".join(map(str, args.files)))
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "sparsegf_partition.md").write_text(to_markdown(rows, command, env))
    print(to_markdown(rows, command, env))
    return 0


if __name__ == "__main__":
    sys.exit(main())
