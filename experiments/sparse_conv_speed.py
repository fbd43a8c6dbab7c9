"""Speed of gfjax.nn.sparse's submanifold convolution against dense convolution and a dense matmul.

    nice .venv/bin/python experiments/sparse_conv_speed.py [--repeats 5] [--dense-max-voxels 12e6]

A 3x3x3 submanifold convolution, 32 -> 32 channels, on the occupied 0.5 m voxels of
`bcts_2` (forest, 824k points) and of ISPRS `samp22`: forward, and forward + backward (the
gradient of a sum of the outputs with respect to features and weights), each the median of
`--repeats` warm calls, compile time apart. In the same run:

- the FLOP rate of a plain dense `jnp.dot` of `(voxels * 27, 32) @ (32, 32)` (forward, and
  forward + backward: the same three products a convolution's gradient takes), the ceiling a
  gather-free engine would reach;
- `lax.conv_general_dilated` on the whole dense grid (zeros where no voxel is), where the
  grid has at most `--dense-max-voxels` cells.

The sparse engine is credited only with the multiply-adds of neighbours that exist
(`pairs * 32 * 32`, times 3 with the backward pass), the dense matmul with all of its own.
Writes `experiments/results/sparse_conv_speed.md`.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import laspy
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from experiments.common import median_time  # noqa: E402
from gfjax.bench.harness import Stopwatch  # noqa: E402
from gfjax.nn import sparse  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("GFJAX_SHARED_DATA", ROOT.parent / "shared" / "data"))
FILES = {"bcts_2": DATA / "lasR_bcts" / "bcts_2.laz", "samp22": DATA / "isprs_filtertest" / "reference" / "samp22-utm.laz"}
RESULTS = ROOT / "experiments" / "results" / "sparse_conv_speed.md"
C = 32
VOXEL_M = 0.5


def compile_time(fn, *args):
    with Stopwatch() as watch:
        fn.lower(*args).compile()
    return watch.wall_s


def voxels(path):
    las = laspy.read(path)
    xyz = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], 1)
    local = (xyz - xyz.min(0)).astype(np.float32)
    vox = sparse.voxelize(local, np.zeros((len(local), 1), np.float32), 0, VOXEL_M)
    n = int(np.sum(np.asarray(vox.tensor.valid)))
    coords = np.asarray(vox.tensor.coords)[:n]
    return len(xyz), coords


def run(name, path, args):
    n_points, coords = voxels(path)
    n = len(coords)
    rng = np.random.default_rng(0)
    feats = jnp.asarray(rng.standard_normal((n, C)), jnp.float32)
    weight = jnp.asarray(rng.standard_normal((27, C, C)) * np.sqrt(2 / (27 * C)), jnp.float32)
    valid = jnp.ones(n, bool)
    coords_j = jnp.asarray(coords)
    with Stopwatch() as watch:
        kmap = sparse.submanifold_map(coords_j, valid)
        jax.block_until_ready(kmap.in_idx)
    first_map_s = watch.wall_s
    map_fn = jax.jit(lambda c, v: sparse.submanifold_map(c, v, block=kmap.block, n_blocks=kmap.n_blocks))
    map_s = median_time(map_fn, coords_j, valid, repeats=args.repeats)
    pairs = int(kmap.n_pairs)

    fwd = jax.jit(lambda f, w: sparse.sparse_conv(f, w, kmap, chunk_blocks=0))
    grad = jax.jit(jax.grad(lambda f, w: jnp.sum(sparse.sparse_conv(f, w, kmap, chunk_blocks=0)), argnums=(0, 1)))
    fwd_compile = compile_time(fwd, feats, weight)
    fwd_s = median_time(fwd, feats, weight, repeats=args.repeats)
    both_s = median_time(lambda f, w: (fwd(f, w), grad(f, w)), feats, weight, repeats=args.repeats)
    chunk = max(1, kmap.n_blocks // 8)
    fwd_chunk = jax.jit(lambda f, w: sparse.sparse_conv(f, w, kmap, chunk_blocks=chunk))
    fwd_chunk_s = median_time(fwd_chunk, feats, weight, repeats=args.repeats)

    rows = n * 27
    a = jnp.asarray(rng.standard_normal((rows, C)), jnp.float32)
    dot = jax.jit(lambda a, w: jnp.dot(a, w))
    dot_grad = jax.jit(jax.grad(lambda a, w: jnp.sum(jnp.dot(a, w)), argnums=(0, 1)))
    dot_s = median_time(dot, a, weight[0], repeats=args.repeats)
    dot_both_s = median_time(lambda a, w: (dot(a, w), dot_grad(a, w)), a, weight[0], repeats=args.repeats)
    del a

    flop = 2.0 * C * C
    row = dict(name=name, points=n_points, voxels=n, pairs=pairs, pairs_per_voxel=pairs / n,
               block=kmap.block, n_blocks=kmap.n_blocks, first_map_s=first_map_s, map_s=map_s,
               fwd_compile_s=fwd_compile, fwd_s=fwd_s, fwd_chunk_s=fwd_chunk_s, chunk=chunk, both_s=both_s,
               dot_s=dot_s, dot_both_s=dot_both_s,
               sparse_gflops_fwd=pairs * flop / fwd_s / 1e9, sparse_gflops_both=3 * pairs * flop / both_s / 1e9,
               dot_gflops_fwd=rows * flop / dot_s / 1e9, dot_gflops_both=3 * rows * flop / dot_both_s / 1e9)
    row["ratio_fwd"] = row["sparse_gflops_fwd"] / row["dot_gflops_fwd"]
    row["ratio_both"] = row["sparse_gflops_both"] / row["dot_gflops_both"]

    extent = coords[:, 1:].max(0) + 1
    cells = int(np.prod(extent))
    row["grid"] = tuple(int(e) for e in extent)
    if cells <= args.dense_max_voxels:
        dense = np.zeros(tuple(extent) + (C,), np.float32)
        dense[coords[:, 1], coords[:, 2], coords[:, 3]] = np.asarray(feats)
        dense = jnp.asarray(dense)
        kernel = weight.reshape(3, 3, 3, C, C)
        conv = jax.jit(lambda x, k: jax.lax.conv_general_dilated(
            x[None], k, (1, 1, 1), "SAME", dimension_numbers=("NDHWC", "DHWIO", "NDHWC"))[0])
        row["dense_conv_s"] = median_time(conv, dense, kernel, repeats=max(1, args.repeats // 2))
        out = np.asarray(conv(dense, kernel))[coords[:, 1], coords[:, 2], coords[:, 3]]
        row["dense_max_abs_diff"] = float(np.max(np.abs(out - np.asarray(fwd(feats, weight)))))
        del dense
    return row


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dense-max-voxels", type=float, default=12e6)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()
    rows = [run(name, path, args) for name, path in FILES.items() if path.exists()]
    load = os.getloadavg()
    lines = [
        "# Sparse 3x3x3 submanifold convolution, 32 -> 32 channels, 0.5 m voxels",
        "",
        f"Command: `nice .venv/bin/python experiments/sparse_conv_speed.py --repeats {args.repeats}`  ",
        f"Machine: {platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__}, {jax.devices()[0].platform}; "
        f"load average {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} at the end. Times are medians of warm calls [s].",
        "",
        "| tile | points | voxels | pairs/voxel | map build | forward | fwd chunked | fwd + bwd | voxels/s fwd+bwd "
        "| sparse GFLOP/s fwd+bwd | dense dot GFLOP/s fwd+bwd | **ratio fwd+bwd** | ratio fwd | dense conv3d |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        dense = (f"{r['dense_conv_s']:.2f} s on {r['grid'][0]}x{r['grid'][1]}x{r['grid'][2]} "
                 f"(max diff {r['dense_max_abs_diff']:.1e})" if "dense_conv_s" in r
                 else f"grid {r['grid'][0]}x{r['grid'][1]}x{r['grid'][2]} over the limit")
        lines.append(
            f"| {r['name']} | {r['points']:,} | {r['voxels']:,} | {r['pairs_per_voxel']:.2f} | {r['map_s']:.3f} s "
            f"| {r['fwd_s']:.3f} s | {r['fwd_chunk_s']:.3f} s | {r['both_s']:.3f} s | {r['voxels'] / r['both_s']:,.0f} "
            f"| {r['sparse_gflops_both']:.1f} | {r['dot_gflops_both']:.1f} | **{r['ratio_both']:.2f}** "
            f"| {r['ratio_fwd']:.2f} | {dense} |")
    lines += [
        "",
        "Ratio = sparse FLOP rate (only the multiply-adds of neighbours that exist) over the FLOP rate of a",
        "dense `jnp.dot` of `(voxels * 27, 32) @ (32, 32)` in the same run. Map build = the kernel map",
        "(binary search of 27 offsets per voxel and the compaction into blocks), jitted, warm; it is shared",
        "by every convolution of a level. `fwd chunked` is the `lax.scan` schedule with an eighth of the",
        "blocks per step. Per tile: " + "; ".join(
            f"{r['name']}: block {r['block']} rows x {r['n_blocks']} blocks, forward compile {r['fwd_compile_s']:.2f} s, "
            f"first map build (compile included) {r['first_map_s']:.2f} s" for r in rows) + ".",
    ]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
