"""`gfjax dtm IN... -o DTM.tif`: a DTM GeoTIFF (and hillshade PNG) from a file's ground points.

Ground is class 2 (`--ground-class` to change it). Cells hold the mean ground elevation; empty
cells are filled by TIN linear interpolation through triangles no longer than `--max-edge`;
the rest is nodata (-9999). The GeoTIFF has the input's CRS and its vertical unit, and is
cloud-optimised (COG: tiled, with overviews), so QGIS or a web map opens it at any zoom.

`--surface chm` writes the canopy height model instead: per cell, the highest point's height
above the ground TIN (negative heights 0, empty cells nodata), on the DTM's lattice.

Several inputs (a survey's tiles) give one raster each in the `-o` folder: each file's TIN also
takes the ground of its neighbours within `--buffer` metres, so the rasters agree across file
borders, and `--mosaic` joins them (a `.vrt` costs no copy).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from gfjax.cli import _job
from gfjax.cli._common import (
    TIF_SUFFIXES,
    add_neighbours_option,
    add_units_option,
    check_inputs,
    neighbours_ground,
    number,
    output_targets,
    positive_float,
    ranged,
)
from gfjax.errors import InputError
from gfjax.io import las as las_io


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("dtm", help="build a DTM GeoTIFF from a file's ground points (class 2), "
                                                "or a canopy height model",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="classified LAS/LAZ files, folders or globs")
    parser.add_argument("-o", "--output", required=True, metavar="DTM.tif",
                        help="GeoTIFF to write, or an existing folder for several inputs (one per input)")
    parser.add_argument("--cell", type=positive_float, default=1.0, metavar="M", help="cell size [m] (default 1)")
    parser.add_argument("--max-edge", type=number, default=100.0, metavar="M",
                        help="longest TIN edge that fills empty cells [m] (default 100; inf: no limit)")
    parser.add_argument("--surface", choices=("ground", "chm"), default="ground",
                        help="ground: the DTM (default); chm: the canopy height model, each cell's highest "
                             "height above ground")
    parser.add_argument("--hillshade", default=None, metavar="PNG",
                        help="also write a hillshade PNG (a folder for several inputs)")
    parser.add_argument("--mosaic", default=None, metavar="MOSAIC.tif|.vrt",
                        help="with several inputs, also join their rasters: one GeoTIFF, or a GDAL virtual "
                             "mosaic (.vrt: the files stay where they are)")
    add_neighbours_option(parser)
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
    inputs = las_io.expand_inputs(args.inputs)
    targets = output_targets(inputs, args.output, suffixes=TIF_SUFFIXES, rename_suffix=".tif")
    shades = ([None] * len(inputs) if not args.hillshade else
              output_targets(inputs, args.hillshade, option="--hillshade", suffixes=(".png",), rename_suffix=".png"))
    if args.mosaic is not None and len(inputs) < 2:
        raise InputError(f"--mosaic {args.mosaic}: joins the rasters of several inputs; got one")
    _job.check_outputs([*(("-o", t, TIF_SUFFIXES) for t in targets),
                        *(("--hillshade", t, (".png",)) for t in shades if t is not None),
                        *((("--mosaic", args.mosaic, (*TIF_SUFFIXES, ".vrt")),) if args.mosaic else ())],
                       inputs=inputs, force=args.force)
    headers = check_inputs(inputs, units=args.units)
    for source, header in zip(inputs, headers, strict=True):
        _check_grid(header, source, args)
    folder, around = neighbours_ground(inputs, args)

    def one(i: int) -> None:
        start = time.perf_counter()
        source, target = inputs[i], targets[i]
        cloud = las_io.read(source, units=args.units)
        ground = cloud.classification == np.uint8(args.ground_class)
        context = None
        if around is not None:     # metres -> the file's units, as its own points
            context = around(i, cloud.xyz_m) / np.array([cloud.horizontal_unit_m, cloud.horizontal_unit_m,
                                                         cloud.vertical_unit_m])
        if args.surface == "chm":
            raster = dtm_lib.chm(cloud, ground, cell_m=args.cell, context_xyz=context)
        else:
            raster = dtm_lib.build(cloud, ground, cell_m=args.cell, max_edge_m=args.max_edge, context_xyz=context)
        raster.to_geotiff(target)
        if shades[i] is not None:
            raster.to_png(shades[i])
        h, w = raster.shape
        filled = float(np.mean(raster.valid)) * 100.0
        near = f" and {len(context):,} of its neighbours'" if context is not None and len(context) else ""
        print(f"{source} -> {target}: {h} x {w} cells of {args.cell:g} m, {filled:.1f} % with a value, "
              f"{int(np.count_nonzero(ground)):,} ground points{near}, {time.perf_counter() - start:.1f} s")

    try:
        for i in range(len(inputs)):
            one(i)
    finally:
        if folder is not None:
            folder.cleanup()
    if args.mosaic is not None:
        h, w = dtm_lib.mosaic(targets, args.mosaic)
        print(f"mosaic of {len(targets)} files -> {args.mosaic} ({h:,} x {w:,} cells)")
    return 0
