"""SMRF's progressive filter as one loop over a traced radius against its radii unrolled.

    nice .venv/bin/python experiments/progressive_program.py --sides 256 512 640 \\
        -o experiments/results/progressive_program.md

Per canonical raster side, the openings r = 1..18 (1 m cells, SMRF's default 18 m window) of a
synthetic terrain with buildings, two ways in one process:

* loop: `gfjax.smrf.stages.progressive_filter` (one `fori_loop`, the disk radius traced,
  `gfjax.raster.morphology` with `max_radius_px`);
* unrolled: the same test with a static `opening` per radius, as the filter had it before.

Reported: compile time, the size of the stored executable (`jax.experimental.serialize_executable`,
as `gfjax.aot` stores it), the time to load it back (median of 5), the warm run time (median of
5) and whether the object masks are equal. Load time is what every fresh process pays before
its first tile, so it enters time to first result.
"""
from __future__ import annotations

import argparse
import functools
import os
import pickle
import time
from pathlib import Path

os.environ["GFJAX_CACHE"] = "0"    # compile here: an executable JAX's cache loaded does not store again

import jax  # noqa: E402
import jax.numpy as jnp
import numpy as np
from jax.experimental import serialize_executable
from raster_speed import terrain  # noqa: E402  (a script beside this one)

from gfjax.bench.harness import Stopwatch, time_call
from gfjax.raster.morphology import opening
from gfjax.smrf import stages

RADIUS_PX = 18


def unrolled(surface, domain, slope, *, cell_m: float, max_radius_px: int):
    """The progressive filter with one static opening per radius."""
    objects = jnp.zeros(surface.shape, dtype=jnp.bool_)
    for radius_px in range(1, max_radius_px + 1):
        opened = jnp.where(domain, opening(surface, domain, radius_px=radius_px, footprint="disk"), surface)
        threshold_m = slope * jnp.asarray(radius_px * cell_m, surface.dtype)
        objects = objects | (domain & stages.is_object(surface, opened, threshold_m))
        surface = opened
    return objects


def window(side: int) -> tuple[np.ndarray, np.ndarray]:
    """`raster_speed`'s terrain with buildings, and a tile's domain padded to `side`."""
    domain = np.zeros((side, side), bool)
    domain[side // 10:, :side - side // 8] = True
    return terrain(side), domain


def measure(fn, args, repeats: int = 5) -> dict:
    with Stopwatch() as watch:
        compiled = jax.jit(fn).lower(*args).compile()
    compile_s = watch.wall_s
    blob = pickle.dumps(serialize_executable.serialize(compiled), protocol=pickle.HIGHEST_PROTOCOL)
    loads, loaded = time_call(lambda: serialize_executable.deserialize_and_load(*pickle.loads(blob)),
                              repeat=repeats, warmup=0)
    out = jax.block_until_ready(loaded(*args))
    runs, _ = time_call(lambda: loaded(*args), repeat=repeats, warmup=0, block=True)
    return dict(compile_s=compile_s, mb=len(blob) / 1e6, load_s=loads.median_s,
                run_s=runs.median_s, out=np.asarray(out))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sides", type=int, nargs="+", default=[256, 512, 640])
    parser.add_argument("-o", "--output", type=Path)
    args = parser.parse_args()
    rows = ["| side | form | compile s | stored MB | load ms | run ms | objects equal |", "|---|---|---:|---:|---:|---:|---|"]
    for side in args.sides:
        z, domain = window(side)
        inputs = (jnp.asarray(z), jnp.asarray(domain), jnp.float32(0.15))
        found = {}
        for name, fn in (("loop", stages.progressive_filter), ("unrolled", unrolled)):
            found[name] = measure(functools.partial(fn, cell_m=1.0, max_radius_px=RADIUS_PX), inputs)
        equal = bool(np.array_equal(found["loop"]["out"], found["unrolled"]["out"]))
        for name, m in found.items():
            rows.append(f"| {side} | {name} | {m['compile_s']:.2f} | {m['mb']:.2f} | {1e3 * m['load_s']:.1f} | "
                        f"{1e3 * m['run_s']:.1f} | {equal} |")
            print(rows[-1], flush=True)
    text = "\n".join([
        "# SMRF's progressive filter: one loop against unrolled radii", "",
        f"Command: `python experiments/progressive_program.py --sides {' '.join(map(str, args.sides))}` "
        f"(openings r = 1..{RADIUS_PX}, 2 CPU cores, JAX {jax.__version__}, {time.strftime('%Y-%m-%d')}).", "",
        *rows, ""])
    if args.output:
        args.output.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
