"""SMRF accuracy on the 11 shared ISPRS reference samples: gfjax vs the `pysmrf` package.

    .venv/bin/python experiments/smrf_isprs.py [--data ../shared/data/isprs_filtertest/reference]
        [--out experiments/results/smrf_isprs.md]

Both run with the defaults of SPEC section 6 (cell 1 m, window 18 m, slope 0.15, threshold
0.5 m, scalar 1.25, all returns), the same for every sample: gfjax `smrf.filter(cloud)`, and
`pysmrf.classify(x, y, z, windows=18)` (its own defaults otherwise: spring inpainting, spline
interpolation). Ground = class 2, everything else non-ground. Per sample: total error, type I,
type II, Cohen's kappa (SPEC section 8), and the unweighted mean over the samples. Times are
wall-clock seconds on this machine, gfjax's first call including JIT compilation.
"""
from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gfjax  # noqa: E402
from experiments.common import ISPRS_REFERENCE, KEYS, ROOT, first_and_again, isprs_samples, score, write_markdown  # noqa: E402
from gfjax import smrf  # noqa: E402
from gfjax.bench.harness import Stopwatch  # noqa: E402


def run_gfjax(cloud):
    t_first, t_again, first, again = first_and_again(lambda: smrf.filter(cloud))
    assert np.array_equal(first.ground, again.ground)
    return again.ground, t_first, t_again


def run_pysmrf(cloud):
    import pysmrf

    xyz = cloud.xyz_m
    with Stopwatch() as watch:
        res = pysmrf.classify(xyz[:, 0], xyz[:, 1], xyz[:, 2], windows=18)
        ground = np.asarray(res.is_ground, bool)
    return ground, watch.wall_s


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=ISPRS_REFERENCE)
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "smrf_isprs.md")
    args = parser.parse_args(argv)
    files = isprs_samples(args.data)
    if not files:
        raise SystemExit(f"{args.data}: no samp*-utm.laz files")

    rows = []
    for path in files:
        cloud = gfjax.read(path)
        ours, t_first, t_again = run_gfjax(cloud)
        peer, t_peer = run_pysmrf(cloud)
        m_ours = score(ours, cloud)
        m_peer = score(peer, cloud)
        name = path.name.split("-")[0]
        rows.append((name, cloud.n_points, m_ours, m_peer, t_first, t_again, t_peer))
        print(f"{name}: gfjax TE {100 * m_ours['total_error']:.2f} % kappa {m_ours['kappa']:.3f} "
              f"({t_first:.1f} s first, {t_again:.2f} s again) | pysmrf TE {100 * m_peer['total_error']:.2f} % "
              f"kappa {m_peer['kappa']:.3f} ({t_peer:.2f} s)", flush=True)

    mean_ours = {k: float(np.mean([r[2][k] for r in rows])) for k in KEYS}
    mean_peer = {k: float(np.mean([r[3][k] for r in rows])) for k in KEYS}
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    import pysmrf

    lines = [
        "# SMRF on the 11 shared ISPRS reference samples: gfjax vs pysmrf",
        "",
        "Command (from the repository root):",
        "",
        "    .venv/bin/python experiments/smrf_isprs.py",
        "",
        f"gfjax commit `{commit}`, pysmrf {getattr(pysmrf, '__version__', '?')}, JAX {jax.__version__} on "
        f"{jax.devices()[0].platform} ({platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"load average {os.getloadavg()[0]:.1f} at the end of the run), float32.",
        "Both with the defaults of SPEC section 6 (cell 1 m, window 18 m, slope 0.15, threshold 0.5 m,",
        "scalar 1.25, all returns), the same for every sample: `gfjax.smrf.filter(cloud)` (harmonic",
        "inpainting) and `pysmrf.classify(x, y, z, windows=18)` (its defaults: spring inpainting, spline",
        "interpolation). Ground = class 2, every other class non-ground. Percentages; the mean is",
        "unweighted over the samples (SPEC section 8).",
        "",
        "| sample | points | gfjax total error | type I | type II | kappa | pysmrf total error | type I | type II | kappa |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name, n, m_ours, m_peer, *_ in rows:
        lines.append(f"| {name} | {n:,} | " + " | ".join(f"{100 * m_ours[k]:.2f}" for k in KEYS) + " | "
                     + " | ".join(f"{100 * m_peer[k]:.2f}" for k in KEYS) + " |")
    lines.append("| **mean** | | " + " | ".join(f"**{100 * mean_ours[k]:.2f}**" for k in KEYS) + " | "
                 + " | ".join(f"**{100 * mean_peer[k]:.2f}**" for k in KEYS) + " |")
    worst = max(rows, key=lambda r: r[2]["total_error"])
    low_kappa = min(rows, key=lambda r: r[2]["kappa"])
    lines += [
        "",
        f"gfjax: mean total error {100 * mean_ours['total_error']:.2f} %, worst sample {worst[0]} "
        f"({100 * worst[2]['total_error']:.2f} %), lowest kappa {low_kappa[0]} ({low_kappa[2]['kappa']:.3f}).",
        f"pysmrf: mean total error {100 * mean_peer['total_error']:.2f} %.",
        "",
        "Wall-clock seconds per sample (gfjax first call includes JIT compilation; the samples have",
        "different raster shapes, so each compiles once; `again` is a second call on the same sample):",
        "",
        "| sample | gfjax first | gfjax again | pysmrf |",
        "| --- | ---: | ---: | ---: |",
    ]
    for name, _, _, _, t_first, t_again, t_peer in rows:
        lines.append(f"| {name} | {t_first:.1f} | {t_again:.2f} | {t_peer:.2f} |")
    write_markdown(args.out, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
