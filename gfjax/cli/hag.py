"""`gfjax hag IN... -o OUT`: each point's height above ground, as PDAL's `HeightAboveGround`.

Ground is the points of class 2 (`--ground-class` to change it), or what `--method` calls ground
(the file is then also classified, as `gfjax filter` would). Heights come from a TIN of the
ground points (`gfjax.dtm.hag`), written as a float64 extra-bytes dimension `HeightAboveGround`
in the file's vertical unit; `--normalize` writes them into z instead (lidR's
`normalize_height`), every other attribute as read. With several inputs the TIN of each file
also takes the ground points of its neighbours within `--buffer` metres (from their classes),
so heights agree across file borders; with `--method` each file is filtered on its own.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from gfjax.cli import _job
from gfjax.cli._common import (
    POINTS_OUTPUT_HELP,
    add_method_options,
    add_neighbours_option,
    add_units_option,
    check_inputs,
    check_written_forms,
    method_setup,
    neighbours_ground,
    output_targets,
    ranged,
)
from gfjax.errors import InputError
from gfjax.io import las as las_io


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("hag", help="height above ground of every point (HeightAboveGround)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="LAS/LAZ files, folders or globs")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help=POINTS_OUTPUT_HELP)
    parser.add_argument("--ground-class", type=ranged("--ground-class"), default=2, metavar="CODE",
                        help="class code of ground points (default 2), when no --method is given")
    add_method_options(parser, method_help="classify ground first with this filter")
    parser.add_argument("--normalize", action="store_true",
                        help="write the heights into z instead of a HeightAboveGround dimension")
    add_neighbours_option(parser)
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    return parser


def run(args: argparse.Namespace) -> int:
    from gfjax.dtm.hag import DESCRIPTION, DIMENSION, height_above_ground

    inputs = las_io.expand_inputs(args.inputs)
    targets = output_targets(inputs, args.output, suffixes=las_io.LAS_SUFFIXES)
    _job.check_outputs([("-o", t, las_io.LAS_SUFFIXES) for t in targets], inputs=inputs, force=args.force)
    runs_method = any(v for v in (args.method, args.preset, args.params, args.set_values))
    setup = method_setup(args) if runs_method else None
    headers = check_inputs(inputs, units=args.units)
    check_written_forms(list(zip(inputs, headers, targets, strict=True)))
    folder, around = neighbours_ground(inputs, args) if setup is None else (None, None)

    def one(i: int, source, target) -> None:
        start = time.perf_counter()
        cloud = las_io.read(source, units=args.units)
        if setup is not None:
            ground = np.asarray(setup.filter(cloud, progress=True).ground, bool)
            cloud = cloud.with_ground(ground)
        else:
            ground = (cloud.classification == np.uint8(args.ground_class)) & ~cloud.ignored
        xyz = cloud.xyz_m
        context = around(i, xyz) if around is not None else np.empty((0, 3))
        if not ground.any() and not len(context):
            raise InputError(f"{source}: no ground point (class {args.ground_class}) to measure heights from"
                             if setup is None else f"{source}: {setup.name} found no ground point")
        n = len(xyz)
        heights_m = height_above_ground(np.concatenate([xyz, context]),
                                        np.concatenate([ground, np.ones(len(context), bool)]))[:n]
        heights = heights_m / cloud.vertical_unit_m                   # the file's vertical unit
        out = cloud.with_z(heights) if args.normalize else cloud.with_extra_dim(DIMENSION, heights,
                                                                              description=DESCRIPTION)
        las_io.write(out, target, force=args.force, input_paths=inputs, exclusive=not args.force)
        print(f"{source} -> {target}: heights above {int(ground.sum()):,} ground points"
              f"{f' and {len(context):,} of its neighbours' if len(context) else ''}, "
              f"{'z' if args.normalize else DIMENSION} from {heights[~ground].min(initial=0):.2f} to "
              f"{heights.max():.2f}, {time.perf_counter() - start:.1f} s")

    try:
        jobs = [_job.Planned(s, None, (0.0, 0.0), t, None, None) for s, t in zip(inputs, targets)]
        index = {s: i for i, s in enumerate(inputs)}
        return _job.run_files(jobs, lambda job: one(index[job.source], job.source, job.target), keep_going=False,
                              report=None)
    finally:
        if folder is not None:
            folder.cleanup()
