"""What the cache of compiled programs (`gfjax.aot`) buys over JAX's persistent compilation
cache alone: whole `gfjax filter` processes with warm caches, per method and file.

    nice .venv/bin/python experiments/program_cache.py \\
        gfjax/data/samp12-utm.laz ../shared/data/lasR_bcts/bcts_1.laz \\
        --methods smrf,pmf,csf,dmf --runs 5 -o experiments/results/program_cache_rerun.md

A: `gfjax filter FILE -o OUT --method M --force` with both caches (the default);
B: the same with `GFJAX_EXPORT_CACHE=0` (JAX's persistent cache only). Both use a fresh
`XDG_CACHE_HOME` made here, warmed by two runs of each command first. The counted runs alternate
A B A B ...; per pair the ratio A/B of wall and CPU (user + system, `os.wait4`) seconds is taken,
so a drift of the machine's speed cancels. Medians are quoted, with min and max.
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


def _run(command: list[str], env: dict) -> tuple[float, float]:
    """(wall s, cpu s) of one whole process (its CPU time from `os.wait4`'s usage: the child's,
    which no clock of this process reads)."""
    with Stopwatch() as watch:
        process = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _, status, usage = os.wait4(process.pid, 0)
    wall = watch.wall_s
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(command)}: exit {os.waitstatus_to_exitcode(status)}")
    return wall, usage.ru_utime + usage.ru_stime


def _spread(values) -> str:
    return f"{statistics.median(values):.3f} ({min(values):.3f}-{max(values):.3f})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--methods", default="smrf,pmf,csf,dmf")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("-o", "--output", default=str(ROOT / "experiments" / "results" / "program_cache_rerun.md"))
    args = parser.parse_args()
    gfjax = [sys.executable, "-c", "import sys; from gfjax.cli.main import main; sys.argv[0] = 'gfjax'; main()"]
    rows = []
    with tempfile.TemporaryDirectory(prefix="gfjax-program-cache-") as tmp:
        base = {**os.environ, "XDG_CACHE_HOME": str(Path(tmp) / "cache"),
                "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        base.pop("GFJAX_EXPORT_CACHE", None)
        envs = {"A": base, "B": {**base, "GFJAX_EXPORT_CACHE": "0"}}
        for path in args.files:
            for method in args.methods.split(","):
                commands = {k: gfjax + ["filter", path, "-o", str(Path(tmp) / f"{k}.laz"), "--method", method, "--force"]
                            for k in envs}
                for _ in range(2):                          # warm both caches
                    for k in envs:
                        _run(commands[k], envs[k])
                times = {"A": [], "B": []}
                for _ in range(args.runs):
                    for k in envs:
                        times[k].append(_run(commands[k], envs[k]))
                wall = {k: [t[0] for t in v] for k, v in times.items()}
                cpu = {k: [t[1] for t in v] for k, v in times.items()}
                rows.append((Path(path).name, method, _spread(wall["A"]), _spread(wall["B"]),
                             _spread([a / b for a, b in zip(wall["A"], wall["B"])]), _spread(cpu["A"]), _spread(cpu["B"]),
                             _spread([a / b for a, b in zip(cpu["A"], cpu["B"])])))
                print(" | ".join(rows[-1]), flush=True)
    header = ("file", "method", "A wall s", "B wall s", "A/B wall", "A cpu s", "B cpu s", "A/B cpu")
    lines = [f"# Program cache: A (both caches) vs B (`GFJAX_EXPORT_CACHE=0`), {args.runs} pairs, median (min-max)",
             "", f"    {' '.join(sys.argv)}", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]
    Path(args.output).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
