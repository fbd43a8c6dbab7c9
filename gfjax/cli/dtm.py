"""`gfjax dtm IN -o DTM.tif`: a DTM GeoTIFF (and hillshade PNG) from a file's ground points.

Ground is class 2 (`--ground-class` to change it). Cells hold the mean ground elevation; empty
cells are filled by TIN linear interpolation through triangles no longer than `--max-edge`;
the rest is nodata (-9999). The GeoTIFF has the input's CRS and its vertical unit, and is
cloud-optimised (COG: tiled, with overviews), so QGIS or a web map opens it at any zoom.

`--surface chm` writes the canopy height model instead: per cell, the highest point's height
above the ground TIN (negative heights 0, empty cells nodata), on the DTM's lattice.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from gfjax.cli import _job
from gfjax.cli._common import TIF_SUFFIXES, add_units_option, check_inputs, number, positive_float, ranged
from gfjax.errors import InputError
from gfjax.io import las as las_io


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("dtm", help="build a DTM GeoTIFF from a file's ground points (class 2), "
                                                "or a canopy height model",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("input", metavar="IN", help="classified LAS/LAZ file")
    parser.add_argument("-o", "--output", required=True, metavar="DTM.tif", help="GeoTIFF to write")
    parser.add_argument("--cell", type=positive_float, default=1.0, metavar="M", help="cell size [m] (default 1)")
    parser.add_argument("--max-edge", type=number, default=100.0, metavar="M",
                        help="longest TIN edge that fills empty cells [m] (default 100; inf: no limit)")
    parser.add_argument("--surface", choices=("ground", "chm"), default="ground",
                        help="ground: the DTM (default); chm: the canopy height model, each cell's highest "
                             "height above ground")
    parser.add_argument("--hillshade", default=None, metavar="PNG", help="also write a hillshade PNG")
    parser.add_argument("--ground-class", type=ranged("--ground-class"), default=2, metavar="CODE",
                        help="class code of ground points (default 2)")
    add_units_option(parser)
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    return parser


def _check_grid(header, source, args: argparse.Namespace) -> None:
    """The DTM over the header's extent must fit the memory budget, before anything is read."""
    from gfjax import dtm as dtm_lib
    from gfjax import limits

    unit_m = las_io.header_units(header, name=str(source), units=args.units).horizontal_m
    extent = tuple(float(hi - lo) * unit_m for lo, hi in zip(header.mins[:2], header.maxs[:2]))
    try:
        limits.check_memory([dtm_lib.memory_estimate(extent, args.cell)])
    except ValueError as err:
        raise InputError(f"{source}: {err}; use a larger --cell or split the file") from None


def run(args: argparse.Namespace) -> int:
    from gfjax import dtm as dtm_lib

    dtm_lib.check_options("", cell_m=args.cell, max_edge_m=args.max_edge)
    inputs = las_io.expand_inputs([args.input])
    if len(inputs) != 1:
        raise InputError(f"{args.input}: gfjax dtm takes one input file, got {len(inputs)}")
    source = inputs[0]
    header = check_inputs(inputs, units=args.units)[0]
    _check_grid(header, source, args)
    _job.check_outputs([("-o", args.output, TIF_SUFFIXES),
                        *([("--hillshade", args.hillshade, (".png",))] if args.hillshade else [])],
                       inputs=inputs, force=args.force)
    start = time.perf_counter()
    cloud = las_io.read(source, units=args.units)
    ground = cloud.classification == np.uint8(args.ground_class)
    if args.surface == "chm":
        dtm = dtm_lib.chm(cloud, ground, cell_m=args.cell)
    else:
        dtm = dtm_lib.build(cloud, ground, cell_m=args.cell, max_edge_m=args.max_edge)
    dtm.to_geotiff(args.output)
    if args.hillshade:
        dtm.to_png(args.hillshade)
    h, w = dtm.shape
    filled = float(np.mean(dtm.valid)) * 100.0
    print(f"{source} -> {args.output}: {h} x {w} cells of {args.cell:g} m, {filled:.1f} % with a value, "
          f"{int(np.count_nonzero(ground)):,} ground points, {time.perf_counter() - start:.1f} s")
    return 0
