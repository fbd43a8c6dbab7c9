"""gfjax CSF against the `cloth-simulation-filter` package: label agreement, accuracy, speed.

For each file: the package (single-threaded: `OMP_NUM_THREADS=1`, set before it is imported)
and `gfjax.csf.filter` run on the same points (`cloud.filter_mask()`, metres) with the same
parameters (the package's defaults: 1 m cloth, rigidness 3, time step 0.65, threshold 0.5 m,
500 iterations, slope smoothing on). Reported per file: agreement (share of points with the
same label), total error / kappa of each against the reference classes (ASPRS 2 = ground),
filter times (gfjax: after one warm-up call, compile time apart), wall-clock and process CPU
seconds (CPU time is the steadier figure on a shared machine), gfjax's simulation steps.

Usage:
  nice .venv/bin/python experiments/csf_agreement.py [FILES...] [--json OUT]
Default files: the 11 ISPRS samples and lasR_bcts/bcts_1.laz of the data folder (docs/development.md, "Data"). Results, in
one command: `experiments/results/csf_agreement.json` and the table `csf_agreement.txt` (beside
the JSON, same stem).
"""
from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import json  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gfjax  # noqa: E402
from experiments.common import DATA, files_parser, isprs_samples, score, write_json  # noqa: E402
from gfjax import csf  # noqa: E402
from gfjax.bench.harness import Stopwatch, time_call  # noqa: E402

DEFAULT_FILES = [*isprs_samples(), DATA / "lasR_bcts" / "bcts_1.laz"]


def run_package(xyz: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Ground labels, wall and CPU seconds of `cloth-simulation-filter` with its defaults."""
    import CSF  # noqa: N811 (the package's module name)
    cloth = CSF.CSF()
    cloth.params.bSloopSmooth = True
    cloth.params.cloth_resolution = 1.0
    cloth.params.rigidness = 3
    cloth.params.time_step = 0.65
    cloth.params.class_threshold = 0.5
    cloth.params.interations = 500
    cloth.setPointCloud(np.ascontiguousarray(xyz, np.float64))
    ground, off = CSF.VecInt(), CSF.VecInt()
    with Stopwatch() as watch:
        cloth.do_filtering(ground, off, False)
    seconds, cpu = watch.wall_s, watch.cpu_s
    labels = np.zeros(len(xyz), bool)
    labels[np.asarray(ground, np.int64)] = True
    return labels, seconds, cpu


def run_gfjax(cloud) -> tuple[np.ndarray, float, float, float, int]:
    """Labels, compile seconds, wall and CPU seconds of a warm call of `gfjax.csf.filter`."""
    # the warm-up call compiles for this grid shape
    timing, result = time_call(lambda: csf.filter(cloud), repeat=1, warmup=1)
    first, seconds, cpu = timing.warmup_s[0], timing.times_s[0], timing.cpu_times_s[0]
    return result.ground, max(first - seconds, 0.0), seconds, cpu, result.diagnostics.steps


def main(argv: list[str] | None = None) -> int:
    parser = files_parser(__doc__, DEFAULT_FILES, "csf_agreement.json")
    args = parser.parse_args(argv)
    rows, lines = [], []
    for path in args.files:
        cloud = gfjax.read(path)
        use = cloud.filter_mask()
        labels, pkg_s, pkg_cpu = run_package(cloud.xyz_m[use])
        pkg = np.zeros(cloud.n_points, bool)
        pkg[use] = labels
        ours, compile_s, ours_s, ours_cpu, steps = run_gfjax(cloud)
        m_pkg = score(pkg, cloud, use)
        m_ours = score(ours, cloud, use)
        pkg, ours = pkg[use], ours[use]
        row = {"file": path.name, "n_points": int(use.sum()), "agreement": float(np.mean(pkg == ours)),
               "te_package": m_pkg["total_error"], "te_gfjax": m_ours["total_error"],
               "kappa_package": m_pkg["kappa"], "kappa_gfjax": m_ours["kappa"],
               "time_package_s": pkg_s, "time_gfjax_s": ours_s, "compile_gfjax_s": compile_s,
               "time_ratio": ours_s / pkg_s, "cpu_package_s": pkg_cpu, "cpu_gfjax_s": ours_cpu,
               "cpu_ratio": ours_cpu / pkg_cpu, "steps_gfjax": steps}
        rows.append(row)
        lines.append(f"{row['file']:16s} n={row['n_points']:7d} agree={row['agreement']:.4f} "
                     f"TE pkg={row['te_package']:.4f} gfjax={row['te_gfjax']:.4f} "
                     f"t pkg={pkg_s:.3f}s gfjax={ours_s:.3f}s (x{row['time_ratio']:.2f}) "
                     f"cpu pkg={pkg_cpu:.3f}s gfjax={ours_cpu:.3f}s (x{row['cpu_ratio']:.2f}) "
                     f"compile={compile_s:.1f}s steps={steps}")
        print(lines[-1], flush=True)
    isprs = [r for r in rows if r["file"].startswith("samp")]
    summary = {
        "mean_agreement": float(np.mean([r["agreement"] for r in rows])),
        "min_agreement": float(np.min([r["agreement"] for r in rows])),
        "mean_te_package_isprs": float(np.mean([r["te_package"] for r in isprs])) if isprs else None,
        "mean_te_gfjax_isprs": float(np.mean([r["te_gfjax"] for r in isprs])) if isprs else None,
        "total_time_package_s": float(np.sum([r["time_package_s"] for r in rows])),
        "total_time_gfjax_s": float(np.sum([r["time_gfjax_s"] for r in rows])),
        "max_time_ratio": float(np.max([r["time_ratio"] for r in rows])),
        "max_cpu_ratio": float(np.max([r["cpu_ratio"] for r in rows])),
    }
    env = {"command": "nice .venv/bin/python " + " ".join(["experiments/csf_agreement.py", *(argv or sys.argv[1:])]),
           "jax": jax.__version__, "device": str(jax.devices()[0]), "cpu_count": os.cpu_count(),
           "platform": platform.platform(), "omp_num_threads": os.environ.get("OMP_NUM_THREADS"),
           "config": str(csf.Config()), "params": {k: float(v) for k, v in vars(csf.Params()).items()}}
    print(json.dumps(summary, indent=1))
    write_json(args.json, env, summary, rows)
    table = args.json.with_suffix(".txt")
    table.write_text("\n".join([f"# {env['command']}", f"# jax {env['jax']}, {env['device']}, "
                                 f"{env['cpu_count']} CPUs, OMP_NUM_THREADS={env['omp_num_threads']}",
                                 *lines, json.dumps(summary, indent=1)]) + "\n")
    print(f"wrote {args.json} and {table}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
