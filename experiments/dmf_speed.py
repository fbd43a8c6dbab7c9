"""DMF speed on `lasR_bcts/bcts_2.laz` (824 k points): whole job and per stage, against
`pysmrf` (windows=18) and `cloth-simulation-filter` (defaults) timed in the same run.

    nice .venv/bin/python experiments/dmf_speed.py          # writes experiments/results/dmf_speed.{md,json}

Order: read, DMF first call (JIT compilation included), DMF warm calls (per-stage seconds from
`Diagnostics.stage_seconds`), peak RSS (before any peer runs), pysmrf, CSF, then the whole
`gfjax filter --method dmf` process (start, read, filter, write): once with whatever cache, then
with the persistent compilation cache warm, interleaved with the same process without the cache of
exported programs (`gfjax.aot`) and with a process that does everything but the filter (its floor). Every warm figure is the best of 3 runs, peers too
(the machine is shared with other jobs). Wall-clock seconds on this machine; the load average at the
start and end is recorded (the machine is shared).

Then where the whole process spends its time (`_anatomy`): a fresh interpreter runs the steps of
`gfjax filter` (the CLI's own calls) with wall-clock marks, JAX's own trace / lower /
compile-or-cache-load durations (`jax.monitoring`), and the interpreter teardown that the
`gfjax` program skips (`gfjax.cli.main._end_process`). Last, the speed path of the cylinder table
(bucket grid) against the KD-tree reference path: time, and DMF labels compared.
"""
from __future__ import annotations

import argparse
import contextlib
import functools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import gfjax  # noqa: E402
from experiments.common import DATA as SHARED_DATA  # noqa: E402  ($GFJAX_SHARED_DATA; docs/development.md, "Data")
from gfjax import dmf  # noqa: E402
from gfjax.bench import harness  # noqa: E402
from gfjax.bench.peers import PEERS  # noqa: E402
from gfjax.bench.run import machine  # noqa: E402
from gfjax.dmf import basal, neighbours, voxels  # noqa: E402

REPEAT = 3
DATA = (SHARED_DATA / "lasR_bcts" / "bcts_2.laz").resolve()


def _cli(path: Path, out: Path, *, export_cache: bool = True) -> float:
    """Seconds of one `gfjax filter --method dmf` process; `export_cache=False` turns off the
    cache of exported programs (`gfjax.aot`, GFJAX_EXPORT_CACHE=0), as before it existed."""
    env = {**os.environ, **({} if export_cache else {"GFJAX_EXPORT_CACHE": "0"})}
    with harness.Stopwatch() as watch:
        subprocess.run([str(ROOT / ".venv" / "bin" / "gfjax"), "filter", str(path), "-o", str(out), "--method", "dmf",
                        "--force"], check=True, capture_output=True, env=env)
    return watch.wall_s


# What every `gfjax filter --method dmf` process does besides filtering: start, the CLI's
# imports (JAX, laspy, scipy, gfjax.dmf), read, label, write, exit as `gfjax` does. argv: IN OUT.
_FLOOR_CHILD = r"""
import sys
from gfjax.cli import main as cli_main
from gfjax import methods
from gfjax.io import las as las_io
import numpy as np
methods.get("dmf")
cloud = las_io.read(sys.argv[1])
labelled = cloud.with_ground(np.zeros(cloud.n_points, bool), reset_nonground=False, used=cloud.filter_mask("all"))
las_io.write(labelled, sys.argv[2], force=True)
cli_main._end_process(0)
"""


def _floor(path: Path, out: Path) -> float:
    """Seconds of a process that does all `gfjax filter --method dmf` does except filtering."""
    with harness.Stopwatch() as watch:
        subprocess.run([sys.executable, "-c", _FLOOR_CHILD, str(path), str(out)], check=True, capture_output=True,
                       cwd=ROOT)
    return watch.wall_s


# The steps of `gfjax filter IN -o OUT --method dmf` (gfjax.cli.filter.run), in a fresh
# interpreter, with a wall-clock mark after each; prints one JSON line. argv: IN OUT TEARDOWN.
_ANATOMY_CHILD = r"""
import time
marks = [("interpreter start", time.time())]
import json, sys
from gfjax import cache
cache.enable()
import jax
from jax import monitoring
jit = {}
def _listen(event, duration_s, **_):
    jit[event] = jit.get(event, 0.0) + duration_s
    jit[event + " count"] = jit.get(event + " count", 0) + 1
monitoring.register_event_duration_secs_listener(_listen)
from gfjax.aot import store
_load = store.load
def _timed_load(*args):
    start = time.time()
    out = _load(*args)
    jit["aot load"] = jit.get("aot load", 0.0) + time.time() - start
    jit["aot load count"] = jit.get("aot load count", 0) + (out is not None)   # misses: no file
    return out
store.load = _timed_load
marks.append(("import jax", time.time()))
from gfjax import methods
from gfjax.io import las as las_io
module = methods.get("dmf")
config, params = methods.make_config_and_params(module)
marks.append(("import gfjax, dmf, laspy, scipy", time.time()))
cloud = las_io.read(sys.argv[1])
marks.append(("read", time.time()))
result = module.filter(cloud, config=config, params=params)
marks.append(("filter (first call in the process)", time.time()))
labelled = cloud.with_ground(result.ground, reset_nonground=False, used=cloud.filter_mask("all"))
las_io.write(labelled, sys.argv[2], force=True)
marks.append(("write", time.time()))
print(json.dumps({"marks": marks, "jit": jit, "stage_seconds": result.diagnostics.stage_seconds}), flush=True)
if sys.argv[3] == "skip":
    cli_main._end_process(0)
"""


def _anatomy(path: Path, out: Path, teardown: str) -> dict:
    """Seconds per step of one `gfjax filter --method dmf` process (warm compilation cache):
    `teardown` "skip" ends it as the `gfjax` program does, "run" with a normal exit.

    Timed by the epoch clock (`time.time`), not `harness.Stopwatch`: the steps are the gaps
    between this process's marks and the child's, which only a clock shared across processes
    can join."""
    start = time.time()
    done = subprocess.run([sys.executable, "-c", _ANATOMY_CHILD, str(path), str(out), teardown], check=True,
                          capture_output=True, text=True, cwd=ROOT)
    end = time.time()
    report = json.loads(done.stdout.strip().splitlines()[-1])
    marks = [("process launch", start), *report["marks"], ("process end", end)]
    steps = {name: t - marks[i - 1][1] for i, (name, t) in enumerate(marks) if i > 0}
    steps["interpreter teardown and exit"] = steps.pop("process end")
    steps = {"python startup" if k == "interpreter start" else k: v for k, v in steps.items()}
    jit = report["jit"]
    return {"total_s": end - start, "steps_s": steps, "stage_seconds": report["stage_seconds"],
            "jit_trace_s": jit.get("/jax/core/compile/jaxpr_trace_duration", 0.0),
            "jit_lower_s": jit.get("/jax/core/compile/jaxpr_to_mlir_module_duration", 0.0),
            "jit_compile_or_cache_load_s": jit.get("/jax/core/compile/backend_compile_duration", 0.0),
            "jit_programs": jit.get("/jax/core/compile/backend_compile_duration count", 0),
            "aot_load_s": jit.get("aot load", 0.0), "aot_programs": jit.get("aot load count", 0)}


def _table_paths(cloud) -> dict:
    """The cylinder table of bcts_2's ND_CE by the bucket grid (speed path) and by the KD-tree
    (reference path): best-of-REPEAT seconds, and whether DMF's labels are the same."""
    config = dmf.Config()
    local = cloud.xyz_m - cloud.xyz_m.min(axis=0)
    cell_m, _ = voxels.voxel_size_m(local, v0=config.v0, fraction=config.sample_fraction, minimum=config.sample_min)
    xy = voxels.bin_voxels(local, cell_m).centroid[:, :2]
    kwargs = dict(radius_m=config.basal_radius_w * cell_m, k=config.basal_neighbours, max_width=config.basal_table_width)
    seconds = {method: harness.time_call(lambda: neighbours.cylinder_table(xy, method=method, **kwargs),
                                         repeat=REPEAT, warmup=1)[0].min_s for method in ("grid", "kdtree")}
    fast = dmf.filter(cloud)
    reference_table = functools.partial(neighbours.cylinder_table, method="kdtree")
    with mock.patch.object(neighbours, "cylinder_table", reference_table):   # the reference path
        reference = dmf.filter(cloud)
    same = bool(np.array_equal(fast.ground, reference.ground) and np.array_equal(fast.instance_id, reference.instance_id))
    return {"grid_s": seconds["grid"], "kdtree_s": seconds["kdtree"], "labels_identical": same, "n_nodes": len(xy)}


IDENTITY_REVISION = "8f9433f"     # the DMF host and basal modules before the speed work
IDENTITY_MODULES = ("neighbours", "basal")


def _reference_swaps(revision: str) -> list[tuple]:
    """`(module, attribute, function)` that put back the table, ND_NG and basal functions of
    `gfjax/dmf/{neighbours,basal}.py` as at git `revision` (the reference paths)."""
    import importlib.util

    reference = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in IDENTITY_MODULES:
            source = subprocess.run(["git", "show", f"{revision}:gfjax/dmf/{name}.py"], check=True, capture_output=True,
                                    text=True, cwd=ROOT).stdout
            path = Path(tmp) / f"_reference_{name}.py"
            path.write_text(source)
            spec = importlib.util.spec_from_file_location(path.stem, path)
            reference[name] = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(reference[name])
    return [(neighbours, "cylinder_table", reference["neighbours"].cylinder_table),
            (neighbours, "nearest_node", reference["neighbours"].nearest_node),
            (basal, "basal_layer", reference["basal"].basal_layer)]


@contextlib.contextmanager
def _swapped(swaps):
    with contextlib.ExitStack() as stack:
        for module, attribute, value in swaps:
            stack.enter_context(mock.patch.object(module, attribute, value))
        yield


def _versus_reference(cloud, revision: str) -> dict:
    """Warm DMF calls of the current code and of the reference modules (`_reference_swaps`),
    interleaved, best of REPEAT each: total and per-stage seconds."""
    swaps = _reference_swaps(revision)
    with _swapped(swaps):
        dmf.filter(cloud)                                      # compile the reference basal loop
    best = {"now": {}, "reference": {}}
    for _ in range(REPEAT):
        for name in best:
            with _swapped(swaps) if name == "reference" else contextlib.nullcontext():
                with harness.Stopwatch() as watch:
                    out = dmf.filter(cloud)
                total = watch.wall_s
            for key, value in {"total": total, **out.diagnostics.stage_seconds}.items():
                best[name][key] = min(best[name].get(key, float("inf")), value)
    return best


def _identity(revision: str, out: Path) -> int:
    """DMF labels, instance ids, basal layer and iteration count of the current code against the
    same code with `gfjax/dmf/{neighbours,basal}.py` as at git `revision`, on every shared LAS
    file, with the default config and each preset. Writes `out` (Markdown); returns the number
    of differences."""
    from experiments.common import DATA as SHARED

    swaps = _reference_swaps(revision)
    configs = {"default": dmf.Config(), **{name: dmf.Config(**over) for name, over in dmf.PRESETS.items()}}
    files = sorted(SHARED.glob("*/*.laz")) + sorted(SHARED.glob("*/*/*.laz"))
    files = [f for f in files if "sites" not in f.parts]
    lines = [f"# DMF speed paths vs `gfjax/dmf/{{{','.join(IDENTITY_MODULES)}}}.py` at git {revision}\n",
             "Command: `nice .venv/bin/python experiments/dmf_speed.py --identity`. Same: ground labels, instance ids, "
             "basal elevations and basal iteration count all equal (bit for bit).\n",
             "| file | points | " + " | ".join(configs) + " |", "|---|---:|" + "---|" * len(configs)]
    differences = 0
    for path in files:
        cloud = gfjax.read(path)
        row = []
        for config in configs.values():
            fast = dmf.filter(cloud, config=config)
            with _swapped(swaps):
                ref = dmf.filter(cloud, config=config)
            same = (np.array_equal(fast.ground, ref.ground) and np.array_equal(fast.instance_id, ref.instance_id)
                    and np.array_equal(fast.diagnostics.basal_z, ref.diagnostics.basal_z)
                    and fast.diagnostics.basal_iterations == ref.diagnostics.basal_iterations)
            differences += not same
            row.append("same" if same else "**different**")
        lines.append(f"| {path.name} | {cloud.n_points:,} | " + " | ".join(row) + " |")
        print(lines[-1], flush=True)
    lines += ["", f"{differences} of {len(files) * len(configs)} runs differ."]
    out.write_text("\n".join(lines) + "\n")
    return differences


def _environment() -> dict:
    """What the figures were measured on (`gfjax.bench.run.machine`), under this script's keys."""
    facts = machine()
    return {**facts, "cpus": facts["nproc"], "device": facts["jax_device"],
            "load_avg_1min": facts["loadavg_1_5_15"][0]}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "dmf_speed.md")
    parser.add_argument("--no-cli", action="store_true", help="skip the whole-process `gfjax filter` timing")
    parser.add_argument("--identity", action="store_true",
                        help=f"only compare DMF's output with its modules at git {IDENTITY_REVISION} on every shared "
                             "file (writes results/dmf_speed_identity.md)")
    args = parser.parse_args(argv)
    if args.identity:
        return int(_identity(IDENTITY_REVISION, args.out.with_name("dmf_speed_identity.md")) > 0)
    env_start = _environment()
    read_timing, cloud = harness.time_call(lambda: gfjax.read(args.data), repeat=1, warmup=0)
    read_s = read_timing.min_s
    n = cloud.n_points
    first_timing, _ = harness.time_call(lambda: dmf.filter(cloud), repeat=1, warmup=0)
    first_s = first_timing.min_s
    warm_s, result, stages = float("inf"), None, {}
    for _ in range(REPEAT):                          # best of REPEAT warm calls (shared machine)
        timing, out = harness.time_call(lambda: dmf.filter(cloud), repeat=1, warmup=0)
        if timing.min_s < warm_s:
            warm_s, result, stages = timing.min_s, out, dict(out.diagnostics.stage_seconds)
    rss_mb = harness.mib(harness.peak_rss_bytes())
    xyz = cloud.xyz_m
    pysmrf_s = harness.time_call(lambda: PEERS["pysmrf"].run(xyz), repeat=REPEAT, warmup=0)[0].min_s
    csf_s = harness.time_call(lambda: PEERS["cloth-simulation-filter"].run(xyz), repeat=REPEAT, warmup=0)[0].min_s
    cli, anatomy = {}, {}
    if not args.no_cli:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out.laz"
            cli = {"first_s": _cli(args.data, out)}
            runs = [(_cli(args.data, out), _cli(args.data, out, export_cache=False), _floor(args.data, out))
                    for _ in range(REPEAT)]                     # interleaved: the same machine state
            cli["warm_cache_s"], cli["no_export_cache_s"], cli["floor_s"] = (min(r[i] for r in runs) for i in range(3))
            anatomy = min((_anatomy(args.data, out, "skip") for _ in range(REPEAT)), key=lambda a: a["total_s"])
            anatomy["teardown_if_run_s"] = _anatomy(args.data, out, "run")["steps_s"]["interpreter teardown and exit"]
    table = _table_paths(cloud)
    versus = _versus_reference(cloud, IDENTITY_REVISION)
    figures = {
        "file": str(args.data.name), "n_points": n, "read_s": read_s,
        "dmf_first_call_s": first_s, "dmf_warm_s": warm_s, "dmf_points_per_s": n / warm_s,
        "dmf_stage_s": stages, "dmf_stage_points_per_s": {k: n / v for k, v in stages.items() if v > 0},
        "peak_rss_mb_after_dmf": rss_mb, "pysmrf_windows18_s": pysmrf_s, "csf_defaults_s": csf_s,
        "speedup_vs_pysmrf": pysmrf_s / warm_s, "speedup_vs_csf": csf_s / warm_s,
        "gfjax_filter_process": cli, "process_anatomy": anatomy, "cylinder_table": table,
        "warm_vs_reference_modules": {"revision": IDENTITY_REVISION, **versus},
        "cell_m": result.diagnostics.cell_m,
        "basal_iterations": result.diagnostics.basal_iterations, "config": str(dmf.Config()),
        "environment_start": env_start, "load_avg_1min_end": _environment()["load_avg_1min"],
    }
    if cli:
        figures["process_over_pysmrf"] = cli["warm_cache_s"] / pysmrf_s
        figures["floor_over_pysmrf"] = cli["floor_s"] / pysmrf_s
    command = "nice .venv/bin/python experiments/dmf_speed.py"
    lines = [f"# DMF speed on {args.data.name} ({n:,} points)\n", f"Command: `{command}`  ",
             f"Machine: {env_start['cpus']} CPUs, {env_start['device']}, jax {env_start['jax']}, float32; "
             f"load average {env_start['load_avg_1min']:.1f} at start, {figures['load_avg_1min_end']:.1f} at end "
             "(shared machine: ratios from one run matter more than seconds)\n",
             "| what | seconds | points/s |", "|---|---:|---:|",
             f"| read (laspy) | {read_s:.2f} | {n / read_s:,.0f} |",
             f"| DMF first call (JIT compile included) | {first_s:.2f} | {n / first_s:,.0f} |",
             f"| **DMF warm call (best of {REPEAT})** | **{warm_s:.2f}** | **{n / warm_s:,.0f}** |"]
    lines += [f"| &nbsp; DMF stage `{k}` | {v:.2f} | {n / v:,.0f} |" for k, v in stages.items() if v > 0]
    lines += [f"| pysmrf.classify(windows=18), best of {REPEAT} | {pysmrf_s:.2f} | {n / pysmrf_s:,.0f} |",
              f"| CSF (cloth-simulation-filter defaults), best of {REPEAT} | {csf_s:.2f} | {n / csf_s:,.0f} |"]
    if cli:
        lines += [f"| `gfjax filter --method dmf` process, cold cache | {cli['first_s']:.2f} | {n / cli['first_s']:,.0f} |",
                  f"| `gfjax filter --method dmf` process, warm cache, best of {REPEAT} | {cli['warm_cache_s']:.2f} | {n / cli['warm_cache_s']:,.0f} |",
                  f"| &nbsp; the same without the exported-program cache (`GFJAX_EXPORT_CACHE=0`), best of {REPEAT} | {cli['no_export_cache_s']:.2f} | {n / cli['no_export_cache_s']:,.0f} |",
                  f"| &nbsp; a process doing all of it but the filter (imports, read, write, exit), best of {REPEAT} | {cli['floor_s']:.2f} | |"]
    lines += ["", f"- DMF warm call vs pysmrf: **{figures['speedup_vs_pysmrf']:.2f}x** faster (target >= 2x); vs CSF {figures['speedup_vs_csf']:.2f}x",
              f"- peak RSS of the process after DMF (before the peers ran): **{rss_mb:,.0f} MiB** (target < 1536)",
              f"- W = {figures['cell_m']} m, basal iterations {figures['basal_iterations']}"]
    if cli:
        lines.append(f"- whole `gfjax filter` process (warm cache) / pysmrf filter call: **{figures['process_over_pysmrf']:.2f}** (target <= 1.5)")
        lines.append(f"- the same process without filtering / pysmrf filter call: **{figures['floor_over_pysmrf']:.2f}**: "
                     f"what is left of the 1.5x budget for the filter is {1.5 * pysmrf_s - cli['floor_s']:.2f} s, "
                     f"the warm filter call alone takes {warm_s:.2f} s")
    if anatomy:
        lines += ["", f"Where one `gfjax filter --method dmf` process (warm compilation cache) spends its "
                      f"{anatomy['total_s']:.2f} s (best of {REPEAT}; the steps of `gfjax.cli.filter.run` with wall-clock marks):", "",
                  "| step | seconds |", "|---|---:|"]
        lines += [f"| {k} | {v:.2f} |" for k, v in anatomy["steps_s"].items()]
        lines += [f"| &nbsp; of which JAX tracing / lowering / compile-or-cache-load of {anatomy['jit_programs']} programs | "
                  f"{anatomy['jit_trace_s']:.2f} / {anatomy['jit_lower_s']:.2f} / {anatomy['jit_compile_or_cache_load_s']:.2f} |",
                  f"| &nbsp; of which loading {anatomy['aot_programs']} stored executables (`gfjax.aot`; partly on the worker thread) | "
                  f"{anatomy['aot_load_s']:.2f} |",
                  "| &nbsp; of which DMF stages (first call) | "
                  + ", ".join(f"{k} {v:.2f}" for k, v in anatomy["stage_seconds"].items()) + " |",
                  f"| interpreter teardown with a normal exit (the `gfjax` program skips it) | {anatomy['teardown_if_run_s']:.2f} |"]
    lines += ["", f"Cylinder table of the {table['n_nodes']:,} ND_CE (Sec. 2.3), best of {REPEAT}: bucket grid (speed path) "
                  f"{table['grid_s']:.3f} s, KD-tree (reference path) {table['kdtree_s']:.3f} s; DMF labels of the two paths "
                  f"identical: **{table['labels_identical']}**"]
    stages_of = lambda b: ", ".join(f"{k} {v:.2f}" for k, v in b.items() if k != "total")   # noqa: E731
    lines += ["", f"Warm DMF call with `gfjax/dmf/{{neighbours,basal}}.py` as at git {IDENTITY_REVISION} (before the speed work; "
                  f"same output, `--identity`) against now, interleaved, best of {REPEAT}: **{versus['reference']['total']:.2f} s** "
                  f"({stages_of(versus['reference'])}) vs **{versus['now']['total']:.2f} s** ({stages_of(versus['now'])})."]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"command": command, **figures}, indent=1, default=str))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
