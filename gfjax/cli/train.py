"""`gfjax train DATA... -o model.eqx`: train SparseGF's network on labelled LAS/LAZ files.

Each file trains on the points the filter's network sees (noise, withheld points and the
cloud's low outliers left out of its inputs and not scored, `gfjax.sparsegf.filter.seen_points`).
Labels: ground = `--ground-class` (2), every other class non-ground. Height-aware loss (lambda 0.5, 6 HAG bins), Adam with a cosine
schedule from 1e-1 to 1e-3, batches of `--batch` patches, random rotation about z (Qin et al.
2026, Sec. 3.3). After every epoch the model is written to `-o` and the training state to
`-o`.state, which `--resume` continues from; the run is deterministic given `--seed` on one
machine (another CPU, number of cores or XLA_FLAGS rounds otherwise: the model file records them).
`--validate FILES` scores the model on labelled files it does not train on after each epoch.
`--dry-run` prints the network's parameter count and the patches per epoch, and stops.
"""
from __future__ import annotations

import argparse

from gfjax.cli import _job
from gfjax.cli._common import add_units_option, check_inputs, ranged
from gfjax.errors import InputError
from gfjax.io.atomic import existing_output_message
from gfjax.sparsegf.config import Config as _Config
from gfjax.sparsegf.config import model_settings
from gfjax.sparsegf.features import FEATURE_SETS

DEFAULT_FEATURES = _Config.features


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("train", help="train the SparseGF model", description=__doc__,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="DATA", help="labelled LAS/LAZ files, folders or globs")
    parser.add_argument("-o", "--output", required=True, metavar="MODEL.eqx", help="model file to write")
    parser.add_argument("--preset", choices=("tiny", "paper"), default="tiny",
                        help="network size: tiny (0.83 M parameters, trains on a CPU) or paper (MinkUNet34C, 37.9 M)")
    parser.add_argument("--epochs", type=ranged("--epochs"), default=12, help="epochs (default 12, the paper's)")
    parser.add_argument("--batch", type=ranged("--batch"), default=4, help="patches per step (default 4, the paper's)")
    parser.add_argument("--lr", type=ranged("--lr"), default=None,
                        help="initial learning rate of the cosine schedule (default 1e-2; the paper's 1e-1 diverged here)")
    parser.add_argument("--seed", type=ranged("--seed"), default=0, help="seed of the weights, rotations and order (default 0)")
    parser.add_argument("--min-patches-per-file", type=ranged("--min-patches-per-file"), default=0, metavar="N",
                        help="draw a file with fewer patches again (new shifts and rotations) until it gives N "
                             "per epoch, so small tiles weigh as much as large ones (default 0: every patch once)")
    parser.add_argument("--max-patches-per-file", type=ranged("--max-patches-per-file"), default=0, metavar="N",
                        help="a random N of a file's patches per epoch when it has more, so a large survey tile "
                             "does not outweigh the others (default 0: all of them)")
    parser.add_argument("--thin-copies", type=ranged("--thin-copies"), default=0, metavar="K",
                        help="also train on K randomly thinned copies of each file, at densities drawn "
                             "log-uniformly down to 0.1 points/m² (default 0)")
    parser.add_argument("--validate", nargs="+", default=(), metavar="FILES", help="labelled files scored after each epoch")
    parser.add_argument("--ground-class", type=ranged("--ground-class"), default=2, help="class code of ground in the labels (default 2)")
    parser.add_argument("--features", choices=FEATURE_SETS, default=DEFAULT_FEATURES,
                        help="per-point inputs: xyz (the paper's coordinates), xyz+tophat (and heights over "
                             "opened minimum surfaces) or xyz+tophat+smrf (and the height over SMRF's ground "
                             f"surface and SMRF's margin; default {DEFAULT_FEATURES})")
    parser.add_argument("--no-compression", action="store_true", help="ablation: no context compression, 1 m voxels")
    parser.add_argument("--no-refinement", action="store_true", help="ablation: no point-wise refinement module")
    parser.add_argument("--no-hag-loss", action="store_true", help="ablation: classification loss only (lambda 0)")
    parser.add_argument("--resume", action="store_true", help="continue from MODEL.eqx.state")
    parser.add_argument("--dry-run", action="store_true", help="print the parameter count and patches per epoch, stop")
    parser.add_argument("--force", action="store_true", help="overwrite an existing model file")
    add_units_option(parser)
    return parser


def _densities(data) -> list[float]:
    """The lowest and highest points per m² of covered area among the training clouds
    (`gfjax.adaptive.measure`): the range `gfjax.sparsegf.filter.trained_density` reads back."""
    from gfjax import adaptive

    values = [1.0 / adaptive.measure(d.xyz_m).spacing_m ** 2 for d in data]
    return [min(values), max(values)]


def _load(paths, units, ground_class):
    """The labelled files' points (`gfjax.io.cloud.Points`), each with a ground point."""
    import numpy as np

    from gfjax.io import las as las_io
    from gfjax.io.cloud import Points

    clouds = []
    for path in paths:
        cloud = las_io.read(path, units=units)
        if not np.any(cloud.classification == ground_class):
            raise InputError(f"{path}: no point of class {ground_class} (ground) to train on")
        clouds.append(Points.of(cloud))
    return clouds


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import os
    import time
    from pathlib import Path

    from gfjax.io import las as las_io

    out = Path(args.output)
    state_path = Path(str(out) + ".state")
    inputs = las_io.expand_inputs(args.inputs)
    validate = las_io.expand_inputs(args.validate) if args.validate else []
    if out.suffix.lower() in las_io.LAS_SUFFIXES:
        raise InputError(f"-o {out}: a model file, not a point cloud (name it .eqx); --force never lets a model "
                         "replace a LAS/LAZ file")
    for data in [*inputs, *validate]:
        if out.exists() and os.path.samefile(out, data):
            raise InputError(f"-o {out}: is a file it trains on; --force never lets a model replace its data")
    if out.exists() and not (args.force or args.resume):
        raise InputError(f"{existing_output_message(f'-o {out}')} (or --resume to continue training it)")
    # --resume continues the model at -o: that one may exist.
    _job.check_outputs([("-o", out, None)], inputs=[*inputs, *validate], force=args.force or args.resume)
    check_inputs([*inputs, *validate], units=args.units)

    import jax

    from gfjax.sparsegf import checkpoint
    from gfjax.sparsegf import train as sgf_train
    from gfjax.sparsegf.config import Config
    from gfjax.sparsegf.features import n_features
    from gfjax.sparsegf.model import NET_PRESETS, count_parameters, init

    config = Config(features=args.features)
    if args.no_compression:
        config = dataclasses.replace(config, compression=False, voxel_m=1.0)
    net_config = dataclasses.replace(NET_PRESETS[args.preset], in_features=n_features(config.features))
    if args.no_refinement:
        net_config = dataclasses.replace(net_config, refine=0)
    clouds = _load(inputs, args.units, args.ground_class)
    data = [sgf_train.labelled_cloud(c, config, ground_class=args.ground_class) for c in clouds]
    data += sgf_train.thinned(clouds, config, copies=args.thin_copies, seed=args.seed, ground_class=args.ground_class)
    del clouds
    n_patches = sgf_train.count_patches(data, config, args.min_patches_per_file, args.max_patches_per_file)
    print(f"{args.preset}: {count_parameters(net_config):,} parameters; about {n_patches} patches per epoch "
          f"from {len(inputs)} files and {len(data) - len(inputs)} thinned copies, up to {args.batch} per step")
    if args.dry_run:
        return 0
    if not args.resume:
        state_path.unlink(missing_ok=True)
    val = [sgf_train.labelled_cloud(c, config, ground_class=args.ground_class)
           for c in _load(validate, args.units, args.ground_class)] or None
    model = init(net_config, key=jax.random.key(args.seed))
    from tqdm import tqdm

    bar = tqdm(desc="train", unit="step")
    started = time.perf_counter()

    def on_step(epoch, step, steps, losses):
        if step == 0:
            bar.reset(total=steps)
            bar.set_description(f"epoch {epoch + 1}/{args.epochs}")
        bar.set_postfix(loss=f"{losses[0]:.3f}")
        bar.update(1)

    def on_epoch(log):
        val_text = f", validation total error {log.val_total_error:.2f} %" if log.val_total_error is not None else ""
        tqdm.write(f"epoch {log.epoch + 1}: loss {log.loss:.4f} (cls {log.loss_cls:.4f}, hag {log.loss_hag:.4f})"
                   f"{val_text}, {log.seconds:.0f} s")

    lam = 0.0 if args.no_hag_loss else sgf_train.LAMBDA
    model, logs = sgf_train.fit(model, data, config=config, epochs=args.epochs, batch_size=args.batch, seed=args.seed,
                              resume_path=state_path, validate=val, lam=lam, lr=args.lr or sgf_train.LR_START,
                              min_patches=args.min_patches_per_file, max_patches=args.max_patches_per_file,
                              on_step=on_step, on_epoch=on_epoch)
    bar.close()
    meta = {"preset": args.preset, "seed": args.seed, "epochs": args.epochs, "batch": args.batch,
            "min_patches_per_file": args.min_patches_per_file, "max_patches_per_file": args.max_patches_per_file,
            "thin_copies": args.thin_copies,
            "files": [Path(p).name for p in inputs], "validate": [Path(p).name for p in validate],
            "config": model_settings(config),
            "inputs": {"density_pts_m2": _densities(data)},
            "machine": sgf_train.machine(),
            "lambda": lam, "lr": args.lr or sgf_train.LR_START, "seconds": time.perf_counter() - started,
            "logs": [log._asdict() for log in logs]}
    checkpoint.save(out, model, meta)
    print(f"{out}: {args.preset} model after {len(logs)} epochs")
    return 0
