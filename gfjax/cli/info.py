"""`gfjax info IN...`: header, CRS, units and points per ASPRS class of LAS/LAZ files."""
from __future__ import annotations

import argparse
import json
from typing import Any

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
    header = cloud.las.header
    classes = asprs.class_counts(cloud.las)
    return {
        "path": cloud.name,
        "version": str(header.version),
        "point_format": int(header.point_format.id),
        "point_count": int(cloud.n_points),
        "compressed": bool(header.are_points_compressed),
        "dimensions": list(header.point_format.dimension_names),
        "extra_dimensions": list(header.point_format.extra_dimension_names),
        "scales": [float(v) for v in header.scales],
        "offsets": [float(v) for v in header.offsets],
        "mins": [float(v) for v in header.mins],
        "maxs": [float(v) for v in header.maxs],
        "vlrs": [type(v).__name__ if type(v).__name__ != "VLR" else f"VLR({v.user_id}, {v.record_id})"
                 for v in header.vlrs],
        "evlrs": len(cloud.las.evlrs or []),
        "crs": crs_lib.describe(cloud.crs),
        "epsg": cloud.crs.to_epsg() if cloud.crs is not None else None,
        "horizontal_unit_m": cloud.horizontal_unit_m,
        "vertical_unit_m": cloud.vertical_unit_m,
        "units": units_lib.describe(units_lib.Units(cloud.horizontal_unit_m, cloud.vertical_unit_m,
                                                    cloud.units_source)),
        "classes": {str(code): {"name": asprs.class_name(code), "count": count}
                    for code, count in classes.items()},
        "ignored_points": int(np.count_nonzero(cloud.ignored)),
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
        f"  CRS         {summary['crs']}",
        f"  units       {summary['units']}",
        "  classes",
    ]
    for code, entry in summary["classes"].items():
        share = 100.0 * entry["count"] / n if n else 0.0
        lines.append(f"    {int(code):>3}  {entry['name']:<28} {entry['count']:>12,}  {share:6.2f} %")
    lines.append(f"  ignored by filters (noise 7/18, withheld): {summary['ignored_points']:,}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    paths = las_io.expand_inputs(args.inputs)
    for path in paths:
        las_io.read_header(path)  # every input checked before anything is printed
    summaries = [summarize(las_io.read(path, units=args.units)) for path in paths]
    if args.json:
        print(json.dumps(summaries if len(summaries) > 1 else summaries[0], indent=2))
    else:
        print("\n\n".join(format_summary(s) for s in summaries))
    return 0
