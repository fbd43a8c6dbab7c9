"""Where `gfjax.sparsegf.filter` spends its time, stage by stage, with the shipped model.

    nice .venv/bin/python experiments/sparsegf_profile.py [--file lasR_bcts/bcts_2.laz] [--repeats 3]

Warm timings (every program compiled by a first call), each the median of `--repeats` calls:

- the whole `filter` call, and SMRF on the same cloud (`gfjax.smrf.filter`), its ratio;
- the stages of the pipeline: SMRF's prior surface (`smrf_prior.smrf_heights`), the per-point
  cloud features, the patches (partition, per-patch features, compression, voxels: host and
  small jitted programs), packing, and the network over every pack (`programs.predict`);
- inside one full pack: the whole network call, the pyramid of kernel maps alone
  (`sparse.build_pyramid`), and its parts (key sort, the stem's kernel-5 table, a kernel-3
  table, one downsampling, the level-0 pairs);
- inside the same pack, the network layer by layer (each layer jitted alone on the pack's
  pyramid): the stem's kernel-5 convolution, then the sum of every other layer;
- the stem read as a pair list instead of its neighbour table (`sparse_conv` against
  `table_conv`, forward and gradient, and the compaction of the kernel-5 table into pairs that
  the pair list needs first);
- the packs' fill: valid voxel rows over the rows the network computes.

Writes `experiments/results/sparsegf_profile.md`.
"""
from __future__ import annotations

import argparse
import importlib
import platform
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import gfjax  # noqa: E402
from experiments.common import DATA, RESULTS, median_time  # noqa: E402
from gfjax import sparsegf  # noqa: E402
from gfjax.nn import sparse  # noqa: E402
from gfjax.nn.sparse import conv as C  # noqa: E402
from gfjax.nn.sparse import keys as K  # noqa: E402
from gfjax.nn.sparse import maps as M  # noqa: E402
from gfjax.sparsegf import pipeline as P  # noqa: E402
from gfjax.sparsegf import programs  # noqa: E402
from gfjax.sparsegf.features import cloud_features  # noqa: E402
from gfjax.sparsegf.smrf_prior import smrf_heights  # noqa: E402

F = importlib.import_module("gfjax.sparsegf.filter")      # the module, not the function of that name


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--file", default="lasR_bcts/bcts_2.laz", help="relative to the shared data folder")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    cloud = gfjax.read(DATA / args.file)
    model, config = sparsegf.load_model()
    xyz = cloud.xyz_m
    rows = []

    def row(name, seconds, note=""):
        rows.append((name, seconds, note))
        print(f"{name}: {seconds:.3f} s {note}", flush=True)

    whole = median_time(lambda: sparsegf.filter(cloud).ground, repeats=args.repeats)
    smrf = median_time(lambda: gfjax.smrf.filter(cloud).ground, repeats=args.repeats)
    row("sparsegf.filter", whole)
    row("smrf.filter", smrf, f"(sparsegf / smrf: {whole / smrf:.1f}x)")
    row("SMRF prior surface", median_time(lambda: smrf_heights(xyz), repeats=args.repeats))
    prior = smrf_heights(xyz)
    row("cloud features", median_time(lambda: cloud_features(xyz, config.features, smrf=prior), repeats=args.repeats))
    feats = cloud_features(xyz, config.features, smrf=prior)
    patches = list(F.patches(xyz, config, cloud_feats=feats))
    row("patches (partition, features, compression, voxels)",
        median_time(lambda: len(list(F.patches(xyz, config, cloud_feats=feats))), repeats=args.repeats), f"({len(patches)} patches)")
    packs = [P.pack(g, P.PACK_SLOTS) for g in P.group(patches, P.PACK_SLOTS)]
    row("pack", median_time(lambda: [P.pack(g, P.PACK_SLOTS) for g in P.group(patches, P.PACK_SLOTS)], repeats=args.repeats))
    row("network over every pack", median_time(lambda: [programs.predict(model, p)[0] for p in packs], repeats=args.repeats),
        f"({len(packs)} packs)")
    valid = sum(int(p.valid.sum()) for p in packs)
    computed = sum(len(p.valid) for p in packs)

    full = max(packs, key=lambda p: int(p.valid.sum()))
    c, v = jnp.asarray(full.coords), jnp.asarray(full.valid)
    n = c.shape[0]
    row("one pack: network", median_time(lambda: programs.predict(model, full)[0], repeats=args.repeats), f"({int(full.valid.sum()):,} voxels)")
    pyramid = jax.jit(sparse.build_pyramid, static_argnames="plan")
    row("one pack: pyramid of kernel maps", median_time(lambda: pyramid(c, v, plan=full.plan), repeats=args.repeats))
    sort = jax.jit(lambda c, v: K.sort_keys(K.pack(c, v)))
    stem = jax.jit(lambda c, v: M.neighbour_table(c, v, c, v, kernel_size=5))
    table3 = jax.jit(lambda c, v: M.neighbour_table(c, v, c, v, kernel_size=3))
    down = jax.jit(lambda c, v: M.downsample(c, v, capacity=n))
    row("  key sort", median_time(lambda: sort(c, v), repeats=args.repeats))
    row("  stem kernel-5 table", median_time(lambda: stem(c, v), repeats=args.repeats))
    row("  one kernel-3 table", median_time(lambda: table3(c, v), repeats=args.repeats))
    row("  one downsampling", median_time(lambda: down(c, v), repeats=args.repeats))
    inner = M.inner_table(stem(c, v), 3)
    block, n_blocks = full.plan.submanifold[0]
    row("  level-0 pairs from the table", median_time(lambda: M.pairs_from_table(
        inner, n_in=n, block=block, n_blocks=n_blocks, in_coords=c, in_valid=v, out_coords=c, out_valid=v), repeats=args.repeats))

    net, state = eqx.nn.inference_mode(model.net), model.state
    pyr = pyramid(c, v, plan=full.plan)
    x0 = sparse.SparseTensor(c, jnp.where(v[:, None], jnp.asarray(full.feats), 0.0), v, 1, full.slots)
    conv = eqx.filter_jit(lambda layer, t, m: layer(t, m).feats)
    block = eqx.filter_jit(lambda b, t, m, st: b(t, m, st)[0].feats)
    row("  layer: stem kernel-5 convolution (table)", median_time(lambda: conv(net.stem, x0, pyr.stem), repeats=args.repeats))
    rest, h = 0.0, sparse.relu(net.stem_norm(net.stem(x0, pyr.stem), state)[0])
    skips = [h]
    for level in range(4):
        rest += median_time(lambda: conv(net.down[level], h, pyr.down[level]), repeats=args.repeats)
        h = sparse.relu(net.down_norm[level](net.down[level](h, pyr.down[level]), state)[0])
        for b in net.enc[level]:
            rest += median_time(lambda: block(b, h, pyr.submanifold[level + 1], state), repeats=args.repeats)
            h = b(h, pyr.submanifold[level + 1], state)[0]
        skips.append(h)
    for step in range(4):
        level = 3 - step
        rest += median_time(lambda: conv(net.up[step], h, pyr.up(level)), repeats=args.repeats)
        h = sparse.relu(net.up_norm[step](net.up[step](h, pyr.up(level)), state)[0])
        h = h.replace_feats(jnp.concatenate([h.feats, skips[level].feats], axis=1))
        for b in net.dec[step]:
            rest += median_time(lambda: block(b, h, pyr.submanifold[level], state), repeats=args.repeats)
            h = b(h, pyr.submanifold[level], state)[0]
    row("  layers: every other convolution and residual block", rest)
    table5 = stem(c, v)
    counts = np.asarray(M.pairs_per_offset(table5, n))
    block5, n_blocks5 = M.plan_blocks(counts)
    compact = jax.jit(M.pairs_from_table, static_argnames=("n_in", "block", "n_blocks"))
    pairs5 = compact(table5, n_in=n, block=block5, n_blocks=n_blocks5, in_coords=c, in_valid=v, out_coords=c, out_valid=v)
    w, f = net.stem.weight, x0.feats
    as_table = jax.jit(lambda w, f: C.table_conv(f, w, pyr.stem))
    as_pairs = jax.jit(lambda w, f: C.sparse_conv(f, w, pairs5))
    grad_table = jax.jit(jax.grad(lambda w, f: jnp.sum(C.table_conv(f, w, pyr.stem) ** 2)))
    grad_pairs = jax.jit(jax.grad(lambda w, f: jnp.sum(C.sparse_conv(f, w, pairs5) ** 2)))
    row("  stem as a table: forward", median_time(lambda: as_table(w, f), repeats=args.repeats))
    row("  stem as pairs: forward", median_time(lambda: as_pairs(w, f), repeats=args.repeats),
        f"({int(counts.sum()):,} pairs, {counts.sum() / int(v.sum()):.1f} of 125 offsets a voxel)")
    row("  stem as a table: gradient", median_time(lambda: grad_table(w, f), repeats=args.repeats))
    row("  stem as pairs: gradient", median_time(lambda: grad_pairs(w, f), repeats=args.repeats))
    row("  kernel-5 table compacted into pairs", median_time(lambda: compact(
        table5, n_in=n, block=block5, n_blocks=n_blocks5, in_coords=c, in_valid=v, out_coords=c, out_valid=v),
        repeats=args.repeats))

    lines = ["# Where SparseGF's time goes", "",
             f"`nice .venv/bin/python experiments/sparsegf_profile.py --file {args.file} --repeats {args.repeats}` "
             f"on {platform.processor() or platform.machine()}, {jax.device_count()} {jax.default_backend()} device(s); "
             f"{cloud.n_points:,} points, the shipped model, warm calls (median of {args.repeats}).", "",
             "| stage | seconds | |", "| --- | ---: | --- |"]
    lines += [f"| {name} | {seconds:.3f} | {note} |" for name, seconds, note in rows]
    seconds = {name: s for name, s, _ in rows}
    lines += ["", f"Packs: {len(packs)}, {valid:,} valid voxel rows of {computed:,} computed "
              f"({100 * valid / computed:.0f} % fill; a pack holds {P.PACK_VOXELS:,} rows); "
              f"{sum(len(p.point_index) for p in patches):,} central point votes for {cloud.n_points:,} points.",
              "",
              f"Shares: the network alone takes {100 * seconds['network over every pack'] / whole:.0f} % of `filter`'s "
              "time (`filter` prepares patches while packs run); "
              f"in a pack, the pyramid {100 * seconds['one pack: pyramid of kernel maps'] / seconds['one pack: network']:.0f} % "
              f"and the stem's kernel-5 table alone "
              f"{100 * seconds['  stem kernel-5 table'] / seconds['one pack: network']:.0f} %; the stem's "
              f"convolution {100 * seconds['  layer: stem kernel-5 convolution (table)'] / seconds['one pack: network']:.0f} % "
              "more (layers timed alone, so the shares are approximate)."]
    (RESULTS / "sparsegf_profile.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
