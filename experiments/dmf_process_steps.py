"""Where one `gfjax filter` process spends its time: wall-clock and CPU seconds of each step.

    PYTHONPATH=CHECKOUT .venv/bin/python experiments/dmf_process_steps.py [--method dmf] [--file PATH] [--runs 3]

Each run is a fresh interpreter that imports the method, then runs `gfjax filter FILE -o
TMP.laz --force` through `gfjax.cli.main` with a wrapper around each step of the command: the
read, the terrain (`adaptive.settle_cloud`), DMF's steps 1-2, 3-6 and 7, the spike guard
(`unstack`, `despike`), `Cloud.with_ground` and the write. CPU seconds are the process's (every
thread) during the step, so a step that waits on a worker thread or JAX still counts their work;
wall-clock seconds depend on the machine's load, CPU seconds much less. Prints one table of
medians over the runs (the program cache warm after the first, untimed run). Default file:
`lasR_bcts/bcts_2.laz` of the shared data. The gfjax timed is the one `$PYTHONPATH` names (two
checkouts side by side: run it once with each).
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from experiments.common import DATA  # noqa: E402

# Run in the child: the steps wrapped, the command run, one JSON line of (step, wall, cpu).
_CHILD = r"""
import functools, importlib, json, sys, time
T = [time.perf_counter(), time.process_time()]
steps = []
def wrap(module, name, label=None):
    fn = getattr(module, name)
    @functools.wraps(fn)
    def timed(*args, **kwargs):
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            steps.append((label or name, time.perf_counter() - wall, time.process_time() - cpu))
    setattr(module, name, timed)
wall, cpu = time.perf_counter(), time.process_time()
from gfjax.cli import main
from gfjax import adaptive, methods, spikes
from gfjax.io import las
from gfjax.io.cloud import Cloud
methods.get(sys.argv[1])    # as the program imports it
steps.append(("import (jax, the method, laspy, scipy)", time.perf_counter() - wall, time.process_time() - cpu))
wrap(las, "read"); wrap(adaptive, "settle_cloud", "terrain (settle_cloud)")
if sys.argv[1] == "dmf":
    dmf = importlib.import_module("gfjax.dmf.filter"); extract = importlib.import_module("gfjax.dmf.extract")
    wrap(dmf, "_voxels", "DMF steps 1-2 (_voxels)"); wrap(dmf, "_layers", "DMF steps 3-6 (_layers)")
    wrap(extract, "extract_ground", "DMF step 7 (extract_ground)")
wrap(spikes, "unstack", "spike guard: unstack"); wrap(spikes, "despike", "spike guard: despike")
wrap(Cloud, "with_ground"); wrap(las, "write")
main._run(["-q", "filter", "--method", sys.argv[1], sys.argv[2], "-o", sys.argv[3], "--force"])
steps.append(("whole run (in process)", time.perf_counter() - T[0], time.process_time() - T[1]))
print(json.dumps(steps))
"""


def run_once(method: str, path: Path, out: Path) -> list[tuple[str, float, float]]:
    # run from the output's folder: `-c` puts the working directory first on the path, and
    # $PYTHONPATH, not a checkout that happens to be there, names the gfjax timed
    done = subprocess.run([sys.executable, "-c", _CHILD, method, str(path), str(out)], capture_output=True,
                          text=True, check=True, cwd=out.parent)
    return [tuple(step) for step in json.loads(done.stdout.strip().splitlines()[-1])]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="dmf")
    parser.add_argument("--file", type=Path, default=DATA / "lasR_bcts" / "bcts_2.laz")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="gfjax-steps-") as scratch:
        out = Path(scratch) / "out.laz"
        run_once(args.method, args.file, out)                     # programs loaded or compiled
        runs = [run_once(args.method, args.file, out) for _ in range(args.runs)]
    print(f"| step ({args.method}, {args.file.name}, median of {args.runs}) | wall s | CPU s |")
    print("| --- | ---: | ---: |")
    for i, (name, _, _) in enumerate(runs[0]):
        wall = statistics.median(run[i][1] for run in runs)
        cpu = statistics.median(run[i][2] for run in runs)
        print(f"| {name} | {wall:.3f} | {cpu:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
