"""`gfjax info IN...`: header, CRS, units and points per ASPRS class of LAS/LAZ files.

Any readable file is described, also one without points or in a geographic CRS (degrees),
which the commands that filter refuse.
"""
from __future__ import annotations

import argparse
import json
import os
from typing import Any

import laspy
import numpy as np

from gfjax.cli._common import add_units_option
from gfjax.io import asprs
from gfjax.io import crs as crs_lib
from gfjax.io import las as las_io
from gfjax.io import units as units_lib
from gfjax.io.cloud import Cloud


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("info", help="header, CRS, units and class counts of LAS/LAZ files",
                                   description=__doc__)
    parser.add_argument("inputs", nargs="+", metavar="IN", help="LAS/LAZ files, folders or globs")
    add_units_option(parser)
    parser.add_argument("--json", action="store_true", help="print the summaries as JSON")
    return parser


def summarize(cloud: Cloud) -> dict[str, Any]:
    """A JSON-ready summary of a cloud: header, CRS, units, class counts, ignored points."""
    units = units_lib.Units(cloud.horizontal_unit_m, cloud.vertical_unit_m, cloud.units_source)
    return _summary(cloud.las, cloud.name, crs=cloud.crs, crs_problem=None, units=units, units_problem=None)


def summarize_file(path: str | os.PathLike, *, units: str | None = None) -> dict[str, Any]:
    """The summary of any readable LAS/LAZ file (`summarize`), also of one without points or
    in a geographic CRS: its units are then None and `units` says why the filters refuse it.

    Raises:
      InputError: a file that is not a readable LAS/LAZ file (`gfjax.io.las.read_points`).
    """
    las = las_io.read_points(path, allow_empty=True)
    try:
        found = las_io.header_crs_units(las.header, name=str(path), units=units)
    except units_lib.UnusableUnits as err:
        crs, problem = crs_lib.read_crs(las.header)
        return _summary(las, str(path), crs=crs, crs_problem=problem, units=None, units_problem=err.reason)
    return _summary(las, str(path), crs=found.crs, crs_problem=found.crs_problem, units=found.units,
                    units_problem=None)


def _summary(las: laspy.LasData, name: str, *, crs, crs_problem: str | None, units: units_lib.Units | None,
             units_problem: str | None) -> dict[str, Any]:
    header = las.header
    classes = asprs.class_counts(las)
    return {
        "path": name,
        "version": str(header.version),
        "point_format": int(header.point_format.id),
        "point_count": len(las.points),
        "compressed": bool(header.are_points_compressed),
        "dimensions": list(header.point_format.dimension_names),
        "extra_dimensions": list(header.point_format.extra_dimension_names),
        "scales": [float(v) for v in header.scales],
        "offsets": [float(v) for v in header.offsets],
        "mins": [float(v) for v in header.mins],
        "maxs": [float(v) for v in header.maxs],
        "vlrs": [type(v).__name__ if type(v).__name__ != "VLR" else f"VLR({v.user_id}, {v.record_id})"
                 for v in header.vlrs],
        "evlrs": len(las.evlrs or []),
        "crs": crs_lib.describe(crs),
        "crs_problem": crs_problem,
        "epsg": crs.to_epsg() if crs is not None else None,
        "horizontal_unit_m": units.horizontal_m if units is not None else None,
        "vertical_unit_m": units.vertical_m if units is not None else None,
        "units": units_lib.describe(units) if units is not None else f"none usable: {units_problem}",
        "classes": {str(code): {"name": asprs.class_name(code), "count": count}
                    for code, count in classes.items()},
        "ignored_points": int(np.count_nonzero(asprs.ignored_mask(las))),
    }


def format_summary(summary: dict[str, Any]) -> str:
    """The summary as aligned text lines."""
    n = summary["point_count"]
    xyz = "xyz"
    lines = [
        f"{summary['path']}",
        f"  LAS {summary['version']}, point format {summary['point_format']}"
        f"{' (LAZ)' if summary['compressed'] else ''}, {n:,} points",
        f"  dimensions  {', '.join(summary['dimensions'])}",
        f"  scales      {'  '.join(f'{a} {v:g}' for a, v in zip(xyz, summary['scales']))}",
        f"  offsets     {'  '.join(f'{a} {v:.10g}' for a, v in zip(xyz, summary['offsets']))}",
        f"  bounds      {'  '.join(f'{a} [{lo:.10g}, {hi:.10g}]' for a, lo, hi in zip(xyz, summary['mins'], summary['maxs']))}",
        f"  VLRs        {', '.join(summary['vlrs']) or 'none'}; EVLRs {summary['evlrs']}",
        f"  CRS         {summary['crs']}"
        f"{' (' + summary['crs_problem'] + ', read as no CRS)' if summary['crs_problem'] else ''}",
        f"  units       {summary['units']}",
        "  classes",
    ]
    for code, entry in summary["classes"].items():
        share = 100.0 * entry["count"] / n if n else 0.0
        lines.append(f"    {int(code):>3}  {entry['name']:<28} {entry['count']:>12,}  {share:6.2f} %")
    if not summary["classes"]:
        lines.append("    none (no points)")
    lines.append(f"  ignored by filters (noise 7/18, withheld): {summary['ignored_points']:,}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    paths = las_io.expand_inputs(args.inputs)
    for path in paths:
        las_io.read_header(path, allow_empty=True)  # every input checked before anything is printed
    summaries = [summarize_file(path, units=args.units) for path in paths]
    if args.json:
        print(json.dumps(summaries if len(summaries) > 1 else summaries[0], indent=2))
    else:
        print("\n\n".join(format_summary(s) for s in summaries))
    return 0
