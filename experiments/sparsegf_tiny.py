"""SparseGF's fixed cost: whole `gfjax filter` processes on tiny files, against SMRF's.

    nice .venv/bin/python experiments/sparsegf_tiny.py --runs 7 \\
        --base-tree ../main -o experiments/results/sparsegf_tiny_rerun.md

Two files are generated here (laspy, point format 1, no CRS): 30 and 1,000 points on a gently
sloping plane at about 2 points/m², a fifth of them lifted 2-10 m (vegetation). Per tree
(this checkout, and `--base-tree`, another checkout of gfjax, when given) a fresh
`XDG_CACHE_HOME` is warmed by two runs of every command, so each counted run is a second run
with warm program caches. The counted runs alternate over trees, methods and files; each run is
timed as a whole process from outside: wall from a monotonic clock, CPU (user + system) and
peak resident memory from the kernel's accounting of the finished child (`os.wait4`).
Medians are quoted, with min and max. With `--stages`, one more process of this tree times
SparseGF's stages in process (`Stopwatch`; the program caches warm, the model already read by
the command's set-up as the command line does).
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from gfjax.bench.harness import Stopwatch  # noqa: E402

SIZES = (30, 1_000)
METHODS = ("sparsegf", "smrf")


def make_file(path: Path, n: int, seed: int = 0) -> None:
    import laspy
    import numpy as np

    rng = np.random.default_rng(seed)
    side = np.sqrt(n / 2.0)
    xy = rng.uniform(0, side, (n, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.05, n)
    lifted = rng.random(n) < 0.2
    z[lifted] += rng.uniform(2, 10, lifted.sum())
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = [0.01, 0.01, 0.01], [500_000, 5_000_000, 0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0] + 500_000, xy[:, 1] + 5_000_000, z
    las.return_number = las.number_of_returns = np.ones(n, np.uint8)
    las.write(path)


def _run(command: list[str], env: dict) -> tuple[float, float, float]:
    """(wall s, cpu s, peak MiB) of one whole process."""
    with Stopwatch() as watch:
        child = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(child.pid, 0)
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(command)}: exit {os.waitstatus_to_exitcode(status)}")
    return watch.wall_s, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def _command(tree: Path, method: str, source: Path, out: Path) -> list[str]:
    return [sys.executable, "-c", f"import sys; sys.path.insert(0, {str(tree)!r}); "
            "from gfjax.cli.main import main; main()",
            "filter", str(source), "-o", str(out), "--method", method, "--force", "-q"]


STAGES = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
from gfjax import cache, spikes
cache.setup()
import importlib
from gfjax.bench.harness import Stopwatch
import gfjax
F = importlib.import_module("gfjax.sparsegf.filter")
from gfjax.sparsegf import pipeline, programs
model, config = F.load_model()
xyz = gfjax.read(sys.argv[2]).xyz_m
rows = []
def timed(name, fn):
    with Stopwatch() as watch:
        out = fn()
    rows.append((name, watch.wall_s, watch.cpu_s))
    return out
if pipeline.fits_tiny_pack(xyz, config):
    timed("network program loaded", lambda: programs.prepare_predict(model, pipeline.tiny_pack(model.net.config.in_features)))
smrf = timed("SMRF's prior (its programs loaded, run)", lambda: F.smrf_heights(xyz))
feats = F.cloud_features(xyz, config.features, smrf=smrf)
prob, votes, n = timed("patches, network, vote", lambda: F.ground_probability(model, xyz, config, cloud_feats=feats))
for name, wall, cpu in rows:
    print(f"{name}\t{wall:.3f}\t{cpu:.3f}")
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--base-tree", type=Path, help="another checkout of gfjax, measured the same way")
    parser.add_argument("--stages", action="store_true")
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args()
    trees = {"this": ROOT} | ({"base": args.base_tree.resolve()} if args.base_tree else {})
    with tempfile.TemporaryDirectory(prefix="sparsegf-tiny-") as tmp:
        tmp = Path(tmp)
        files = {n: tmp / f"tiny{n}.laz" for n in SIZES}
        for n, path in files.items():
            make_file(path, n)
        envs = {}
        for name in trees:
            (tmp / f"cache-{name}").mkdir(mode=0o700)
            envs[name] = {**os.environ, "XDG_CACHE_HOME": str(tmp / f"cache-{name}")}
            envs[name].pop("GFJAX_CACHE", None)
        jobs = [(t, m, n) for t in trees for m in METHODS for n in SIZES]
        for t, m, n in jobs + jobs:                                   # compile, then warm
            _run(_command(trees[t], m, files[n], tmp / f"{t}-{m}-{n}.laz"), envs[t])
        found: dict = {job: [] for job in jobs}
        for _ in range(args.runs):
            for t, m, n in jobs:
                found[t, m, n].append(_run(_command(trees[t], m, files[n], tmp / f"{t}-{m}-{n}.laz"), envs[t]))
        stages = None
        if args.stages:
            done = subprocess.run([sys.executable, "-c", STAGES, str(ROOT), str(files[SIZES[0]])], env=envs["this"],
                                  check=True, capture_output=True, text=True)
            stages = [line.split("\t") for line in done.stdout.splitlines() if "\t" in line]
    lines = [f"`{' '.join([Path(sys.executable).name, *sys.argv])}`; {args.runs} counted runs of each command "
             f"(second runs, warm caches), load average {os.getloadavg()[0]:.1f} at the end.", "",
             "| tree | method | points | wall s median (min-max) | cpu s median | peak MiB median (min-max) |",
             "|---|---|---|---|---|---|"]

    def spread(values, fmt):
        return f"{format(statistics.median(values), fmt)} ({format(min(values), fmt)}-{format(max(values), fmt)})"

    for (t, m, n), runs in found.items():
        wall, cpu, peak = zip(*runs)
        lines.append(f"| {t} | {m} | {n:,} | {spread(wall, '.2f')} | {statistics.median(cpu):.2f} | "
                     f"{spread(peak, '.0f')} |")
    if stages:
        lines += ["", f"SparseGF's stages on {SIZES[0]} points (this tree, one process):", "",
                  "| stage | wall s | cpu s |", "|---|---|---|"]
        lines += [f"| {name} | {wall} | {cpu} |" for name, wall, cpu in stages]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.output:
        args.output.write_text(text)


if __name__ == "__main__":
    main()
