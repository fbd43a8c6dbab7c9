"""A COPC file of a small octree, for the tests of reading one a box at a time."""
from __future__ import annotations

from pathlib import Path

import laspy

from gfjax.io import copc, copc_writer


def write_copc(las: laspy.LasData, path: str | Path, *, depth: int = 4, capacity: int = 256) -> laspy.LasData:
    """Write `las` as a COPC file (`gfjax.io.copc_writer.write`) of an octree at most `depth`
    levels deep whose nodes hold up to `capacity` points (the deepest, any number), so a box
    query reads the coarse nodes and only the fine ones that meet the box.

    Returns:
      The points as written (point format 6, 7 or 8, LAS 1.4, in the file's order),
      without COPC's records, so laspy writes them as plain LAS.
    """
    copc_writer.write(las, path, name=str(path), wkt=None, node_points=capacity, max_depth=depth)
    written = laspy.read(path)
    header, evlrs = copc.without_layout(written.header, written.evlrs)
    plain = laspy.LasData(header, written.points)
    plain.evlrs = evlrs
    return plain
