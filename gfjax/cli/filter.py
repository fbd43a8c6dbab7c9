"""`gfjax filter IN... -o OUT`: classify ground points and write LAS/LAZ (SPEC sections 1, 2).

Ground points get class 2; non-ground points that were class 2 become 1, others keep their
class (all become 1 with `--reset-nonground`); noise (7, 18), withheld points and, with
`--returns last`, non-last returns keep their class. Nothing else in the file changes, except
an `instance_id` extra-bytes dimension with `--instances`. With several inputs (or a glob),
OUT is an existing folder and each output has its input's name.

Every input and output is checked before the first file is filtered, so a bad option or
path fails at once and leaves no file behind.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from gfjax.cli._common import (TIF_SUFFIXES, add_method_options, add_units_option, method_setup,
                               nonnegative_float, output_targets, positive_float)
from gfjax.errors import InputError
from gfjax.io import las as las_io


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("filter", help="classify ground points, write LAS/LAZ (and a DTM)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="LAS/LAZ files, folders or globs")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="output .las/.laz file, or an existing folder for several inputs")
    add_method_options(parser, method_help="ground filter (default: gfjax.methods.DEFAULT_METHOD)")
    parser.add_argument("--tile-size", type=positive_float, default=None, metavar="M",
                        help="tile core side [m] (method default, 500)")
    parser.add_argument("--buffer", type=nonnegative_float, default=None, metavar="M",
                        help="context around each tile [m] (method default, 50)")
    parser.add_argument("--returns", choices=("all", "last"), default="all",
                        help="returns the filter uses (default all)")
    parser.add_argument("--reset-nonground", action="store_true",
                        help="set every non-ground point to class 1 (default: only former class 2)")
    parser.add_argument("--instances", action="store_true",
                        help="add a uint32 extra-bytes dimension instance_id (methods that give one)")
    parser.add_argument("--dtm", default=None, metavar="DTM.tif",
                        help="also write a DTM GeoTIFF from the ground points (a folder for several inputs)")
    parser.add_argument("--cell", type=positive_float, default=1.0, metavar="M",
                        help="DTM cell size [m] (default 1)")
    add_units_option(parser)
    parser.add_argument("--trust-data", action="store_true",
                        help="when a header's point count disagrees with the points the file holds, "
                             "filter the points present (and say so) instead of stopping")
    parser.add_argument("--force", action="store_true", help="overwrite input files")
    return parser


def _tiling_overrides(args: argparse.Namespace, module) -> dict[str, float]:
    fields = {f.name for f in dataclasses.fields(module.Config)}
    overrides = {}
    for option, key, value in (("--tile-size", "tile_size_m", args.tile_size),
                               ("--buffer", "buffer_m", args.buffer)):
        if value is None:
            continue
        if key not in fields:
            raise InputError(f"{option}: method {module.__name__.split('.')[-1]} does not tile (no {key})")
        overrides[key] = value
    return overrides


def run(args: argparse.Namespace) -> int:
    inputs = las_io.expand_inputs(args.inputs)
    header_counts = {path: las_io.read_header(path, trust_data=args.trust_data).point_count for path in inputs}
    targets = output_targets(inputs, args.output, suffixes=las_io.LAS_SUFFIXES)
    for target in targets:
        las_io.check_output(target, force=args.force, input_paths=inputs, suffixes=las_io.LAS_SUFFIXES, option="-o")
    dtm_targets = [None] * len(inputs)
    if args.dtm is not None:
        dtm_targets = output_targets(inputs, args.dtm, option="--dtm", suffixes=TIF_SUFFIXES,
                                     rename_suffix=".tif")
        for target in dtm_targets:
            las_io.check_output(target, force=args.force, input_paths=inputs, suffixes=TIF_SUFFIXES,
                                option="--dtm")
        if set(map(Path.resolve, dtm_targets)) & set(map(Path.resolve, targets)):
            raise InputError(f"--dtm {args.dtm}: same path as an output point cloud")
        from gfjax import dtm as dtm_lib  # imported before any filtering: fail early if absent
    setup = method_setup(args)
    tiling = _tiling_overrides(args, setup.module)
    if tiling:
        try:
            setup = setup._replace(config=dataclasses.replace(setup.config, **tiling))
        except ValueError as err:
            raise InputError(f"--tile-size/--buffer: {err}") from None

    jobs, say = list(zip(inputs, targets, dtm_targets)), print
    if len(inputs) > 1:                     # a progress bar over files (tqdm: 40 ms to import)
        from tqdm.auto import tqdm

        jobs, say = tqdm(jobs, desc="files", unit="file"), tqdm.write
    for source, target, dtm_target in jobs:
        start = time.perf_counter()
        cloud = las_io.read(source, units=args.units, trust_data=args.trust_data)
        if cloud.n_points != header_counts[source]:
            print(f"gfjax: warning: {source}: header says {header_counts[source]:,} points, the file holds "
                  f"{cloud.n_points:,}; filtering the {cloud.n_points:,} points present (--trust-data)",
                  file=sys.stderr)
        result = setup.filter(cloud, returns=args.returns, progress=True)
        ground = np.asarray(result.ground, dtype=bool)
        labelled = cloud.with_ground(ground, reset_nonground=args.reset_nonground,
                                     used=cloud.filter_mask(args.returns))
        if args.instances:
            if result.instance_id is None:
                raise InputError(f"--instances: method {setup.name} gives no instance ids")
            labelled = labelled.with_extra_dim("instance_id", np.asarray(result.instance_id, dtype=np.uint32),
                                               description="object instance, 0 = none")
        las_io.write(labelled, target, force=args.force, input_paths=inputs)
        if dtm_target is not None:
            dtm_lib.build(cloud, ground, cell_m=args.cell).to_geotiff(dtm_target)
        seconds = time.perf_counter() - start
        n_ground = int(np.count_nonzero(ground))
        message = (f"{source} -> {target}: {setup.name}, {n_ground:,} ground of {cloud.n_points:,} points "
                   f"({100.0 * n_ground / cloud.n_points:.1f} %), {seconds:.1f} s "
                   f"({cloud.n_points / max(seconds, 1e-9):,.0f} points/s)")
        say(message)
    return 0
