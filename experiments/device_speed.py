"""SparseGF and SMRF on whatever device JAX runs on (CPU here, a GPU where one is lent).

    GFJAX_SHARED_DATA=... python experiments/device_speed.py --out results/device_speed_gpu.json

Per file (the forest tile `bcts_2` and the ISPRS test samples), the first `filter` call
(compiles) and the median of `--repeat` warm calls, for SMRF's defaults and the shipped
SparseGF model; then the time of one training step of SparseGF's `tiny` and `paper` presets
on packs of `bcts_1` (the median of `--steps` steps after the first, which compiles). Each
part is written to the JSON as soon as it is measured, so a run cut short keeps what it did.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import numpy as np  # noqa: E402

import gfjax  # noqa: E402
from experiments.common import DATA, ISPRS_REFERENCE, RESULTS  # noqa: E402
from gfjax.bench.harness import Stopwatch, time_call  # noqa: E402

FILES = {"bcts_2": DATA / "lasR_bcts" / "bcts_2.laz",
         **{s: ISPRS_REFERENCE / f"{s}-utm.laz" for s in ("samp22", "samp42", "samp54")}}


def filter_times(name, run, clouds, repeat):
    rows = {}
    for label, cloud in clouds.items():
        timing, _ = time_call(lambda: run(cloud), repeat=repeat, warmup=1, block=True)
        first = timing.warmup_s[0]
        rows[label] = {"points": cloud.n_points, "first_s": first, "warm_s": timing.median_s}
        print(f"{name} {label}: first {first:.2f} s, warm {rows[label]['warm_s']:.2f} s", flush=True)
    return rows


def train_step_times(preset, cloud, steps):
    import dataclasses

    from gfjax.sparsegf import train
    from gfjax.sparsegf.config import Config
    from gfjax.sparsegf.features import n_features
    from gfjax.sparsegf.model import NET_PRESETS, count_parameters, init

    config = Config()
    net_config = dataclasses.replace(NET_PRESETS[preset], in_features=n_features(config.features))
    model = init(net_config, key=jax.random.key(0))
    data = [train.labelled(cloud.xyz_m, cloud.classification)]
    batches = list(train.training_batches(data, config, batch_size=4, rng=np.random.default_rng(0)))
    model = train.calibrate(model, batches)
    size = len(batches[0].packed.valid)
    batches = [b for b in batches if len(b.packed.valid) == size]     # one compiled shape
    opt, opt_state = train.init(model)
    times = []
    for i in range(steps + 1):
        step = batches[i % len(batches)]
        with Stopwatch() as watch:
            model, opt_state, loss, _ = train.train_step(model, opt_state, step, opt, 0.0, train.LR_START)
            jax.block_until_ready(loss.total)
        times.append(watch.wall_s)
    voxels = [int(b.packed.valid.sum()) for b in batches]
    return {"parameters": count_parameters(net_config), "first_s": times[0], "step_s": statistics.median(times[1:]),
            "steps_timed": len(times) - 1, "pack_rows": size, "voxels_per_pack_median": int(np.median(voxels))}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS / "device_speed.json")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--parts", default="smrf,sparsegf,train-tiny,train-paper")
    args = parser.parse_args()
    parts = args.parts.split(",")
    out = {"device": str(jax.devices()[0]), "platform": jax.default_backend(), "jax": jax.__version__,
           "python": platform.python_version(), "cpus": os.cpu_count(), "results": {}}
    print(out, flush=True)

    def save():
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=1, default=float))

    clouds = {k: gfjax.read(p) for k, p in FILES.items()}
    for part in parts:
        watch = Stopwatch()
        try:
            if part == "smrf":
                res = filter_times("smrf", lambda c: gfjax.smrf.filter(c).ground, clouds, args.repeat)
            elif part == "sparsegf":
                from gfjax import sparsegf
                model, config = sparsegf.load_model(None)
                res = filter_times("sparsegf", lambda c: sparsegf.filter(c, model=model, config=config).ground,
                                   clouds, args.repeat)
            elif part.startswith("train-"):
                res = train_step_times(part.split("-", 1)[1], gfjax.read(DATA / "lasR_bcts" / "bcts_1.laz"),
                                       args.steps)
                print(part, res, flush=True)
            else:
                raise SystemExit(f"unknown part {part}")
        except Exception as err:            # keep the other parts' figures
            res = {"error": f"{type(err).__name__}: {err}"}
            print(part, res, flush=True)
        res_time = watch.wall_s
        out["results"][part] = {"seconds": res_time, **({"files": res} if part in ("smrf", "sparsegf") else res)}
        save()


if __name__ == "__main__":
    main()
