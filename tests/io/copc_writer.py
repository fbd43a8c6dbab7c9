"""A COPC file written from a LAS/LAZ file with copc-lib (the tests' writer: gfjax only reads COPC)."""
from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np


def write_copc(las: laspy.LasData, path: str | Path, *, depth: int = 4, capacity: int = 256) -> laspy.LasData:
    """Write `las` as a COPC file of an octree at most `depth` levels deep whose nodes hold up
    to `capacity` points (the deepest, any number), so a box query reads the coarse nodes and
    only the fine ones that meet the box.

    Returns:
      The points as written (point format 6 or 7, LAS 1.4, the file's order): `laspy.read(path)`
      gives them back, the same points in node order.
    """
    import copclib as copc

    fmt = 7 if "red" in las.point_format.dimension_names else 6
    las = laspy.convert(las, point_format_id=fmt, file_version="1.4")
    header = las.header
    config = copc.CopcConfigWriter(fmt, copc.Vector3(*header.scales), copc.Vector3(*header.offsets), "")
    xyz = np.column_stack([las.x, las.y, las.z])
    lo, hi = xyz.min(axis=0), xyz.max(axis=0)
    center, half = (lo + hi) / 2, float((hi - lo).max()) / 2 + 1.0
    info = config.copc_info
    info.center_x, info.center_y, info.center_z = map(float, center)
    info.halfsize = half
    info.spacing = 2 * half / 128
    config.las_header.min, config.las_header.max = copc.Vector3(*lo), copc.Vector3(*hi)

    # As COPC builders fill an octree: points in a shuffled order, each into the shallowest
    # node of its path that holds fewer than `capacity`, so every node's ancestors are full
    unit = (xyz - (center - half)) / (2 * half)
    cells = [np.minimum((unit * (1 << d)).astype(np.int64), (1 << d) - 1) for d in range(depth + 1)]
    count: dict[tuple[int, int, int, int], int] = {}
    members: dict[tuple[int, int, int, int], list[int]] = {}
    for i in np.random.default_rng(0).permutation(len(las.points)):
        for d in range(depth + 1):
            key = (d, *map(int, cells[d][i]))
            if count.get(key, 0) < capacity or d == depth:
                count[key] = count.get(key, 0) + 1
                members.setdefault(key, []).append(int(i))
                break
    nodes = {key: np.sort(np.asarray(index)) for key, index in members.items()}
    writer = copc.FileWriter(str(path), config)
    order = []
    for key in sorted(nodes):
        index = nodes[key]
        writer.AddNode(copc.VoxelKey(*key), copc.VectorChar(np.frombuffer(las.points.array[index].tobytes(), np.int8)))
        order.append(index)
    writer.Close()
    las.points = las.points[np.concatenate(order)]
    return las
