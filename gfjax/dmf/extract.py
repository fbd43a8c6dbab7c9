"""DMF step 7: GF-support nodes and the final point rule (Wu et al. 2025, Sec. 2.6).

Support nodes sit at the centres of the NGNEM cells that hold an ND_CE: TP_G on ground cells,
TPN on object cells (NGNEM_RC). A TP_G whose column's ND_CE is in ND_NG takes that node's
elevation; every other node takes the mean of its `fill_neighbours` (24) nearest such TP_G
(2D). All nodes are lowered by `v1 * W`. A node's own elevation is its ND_CE's (the centroid of
the column's lowest voxel, the paper) or, as a reading (R), the column's lowest point
(`column_lowest_z`). Host part: the KD-tree queries (scipy). The per-point
bookkeeping is jitted JAX (`gfjax.dmf.programs`).

Final rules (`Config.final_rule`, R):
* "m_nearest" (the paper's bidirectional KD-tree engine): each point finds its 3D-nearest
  support node; M = ceil(mean points per node that is someone's nearest); each TP_G takes its M
  nearest points; a point is ground when it is among those and its own nearest node is a TP_G.
* "height": a point is ground when it lies at most a threshold (`Params.threshold_m(W)`) above
  the support surface (nodes not lowered; bilinear between cell centres, empty cells from the
  nearest node).
* "both": ground when both rules say so.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np
from scipy.spatial import cKDTree

from gfjax.dmf import programs
from gfjax.dmf.config import Config, Params
from gfjax.dmf.shapes import raster_shape
from gfjax.dmf.voxels import Voxels
from gfjax.tiling.buckets import canonical_capacity
from gfjax.tiling.tiles import Tiling

__all__ = ["extract_ground", "SupportNodes", "support_nodes", "column_lowest_z", "m_nearest_ground", "height_ground"]


class SupportNodes(NamedTuple):
    """GF-support nodes, one per NGNEM cell holding an ND_CE.

    Attributes:
      xyz: cell-centre x, y and the lowered elevation, float64 `(s, 3)`, local metres.
      z_surface: the elevation before lowering, float64 `(s,)` [m].
      ground: True for TP_G, False for TPN, bool `(s,)`.
      cell: flat cell index, int64 `(s,)` (equals `Voxels.cell`).
      from_ndng: the elevation is the ND_NG node's own (not interpolated), bool `(s,)`.
    """

    xyz: np.ndarray
    z_surface: np.ndarray
    ground: np.ndarray
    cell: np.ndarray
    from_ndng: np.ndarray


def column_lowest_z(points: np.ndarray, vox: Voxels) -> np.ndarray:
    """The lowest point of each ND_CE's column (so of its lowest voxel), float64 `(m,)` [m].

    Args:
      points: the local coordinates `vox` was binned from, float64 `(n, 3)` metres.
      vox: voxel columns (`bin_voxels(points, W)`).
    """
    h, w = vox.shape
    lowest = np.full(h * w, np.inf)
    np.minimum.at(lowest, vox.point_cell, points[:, 2])
    return lowest[vox.cell]


def support_nodes(vox: Voxels, object_cell: np.ndarray, in_ndng: np.ndarray, *, v1: float,
                  fill_neighbours: int, support_z: str = "ndng", own_z: np.ndarray | None = None) -> SupportNodes:
    """Build the GF-support node layer (Sec. 2.6, first two paragraphs).

    Args:
      vox: voxel columns (`bin_voxels`).
      object_cell: NGNEM_RC per flat cell, bool `(h * w,)`.
      in_ndng: ND_CE index is in ND_NG, bool `(m,)`.
      v1: lowering factor (paper: 2); fill_neighbours: 24 in the paper.
      support_z: (R) "ndng": a TP_G keeps its own elevation only when its column's ND_CE is
        in ND_NG (the paper); "ndce": every TP_G keeps its column's ND_CE elevation.
      own_z: the elevation a node takes from its own column, float64 `(m,)` [m] (default: the
        ND_CE centroid's z, the paper; `column_lowest_z` for `support_elevation="lowest"`).

    Returns: `SupportNodes`.
    """
    h, w = vox.shape
    cell_m = vox.cell_m
    row, col = vox.cell // w, vox.cell % w
    x = (col + 0.5) * cell_m
    y = (h - 1 - row + 0.5) * cell_m
    ground = ~object_cell[vox.cell]
    known = ground & in_ndng if support_z == "ndng" else ground
    z = np.array(vox.centroid[:, 2] if own_z is None else own_z, dtype=np.float64)
    if known.any() and not known.all():
        xy = np.stack([x, y], axis=1)
        k = min(fill_neighbours, int(known.sum()))
        _, idx = cKDTree(xy[known]).query(xy[~known], k=k, workers=-1)     # every core: the same rows
        idx = np.asarray(idx).reshape(int((~known).sum()), k)
        z[~known] = z[known][idx].mean(axis=1)
    lowered = z - v1 * cell_m
    return SupportNodes(xyz=np.stack([x, y, lowered], axis=1), z_surface=z, ground=ground,
                        cell=vox.cell, from_ndng=known)


def m_nearest_ground(points: np.ndarray, nodes: SupportNodes, *, points_tree: cKDTree | None = None) -> tuple[np.ndarray, int]:
    """The paper's bidirectional KD-tree rule (Sec. 2.6, Fig. 4).

    Args:
      points: local coordinates, float64 `(n, 3)` metres.
      nodes: the support nodes.
      points_tree: a `cKDTree` of `points`, reused if given (OKDT).

    Returns: `(ground bool (n,), M)`.
    """
    n = len(points)
    if n == 0 or len(nodes.xyz) == 0:
        return np.zeros(n, bool), 0
    _, nearest = cKDTree(nodes.xyz).query(points, k=1, workers=-1)         # TKDT
    counts = np.bincount(nearest, minlength=len(nodes.xyz))
    m = max(1, math.ceil(counts[counts > 0].mean() - 1e-9))
    tree = cKDTree(points) if points_tree is None else points_tree
    g_nodes = nodes.xyz[nodes.ground]
    if len(g_nodes) == 0:
        return np.zeros(n, bool), m
    _, taken = tree.query(g_nodes, k=min(m, n), workers=-1)
    taken = np.asarray(taken).reshape(len(g_nodes), -1).astype(np.int32)
    ground = programs.mark_ground(nearest.astype(np.int32), nodes.ground, taken, n_points=n)
    return np.asarray(ground), m


def height_ground(points: np.ndarray, nodes: SupportNodes, vox: Voxels, threshold_m,
                  tiling: Tiling | None = None) -> np.ndarray:
    """Alternative final rule: ground when `z - S(x, y) <= threshold_m`, S the support surface
    (not lowered) sampled bilinearly between cell centres. Returns bool `(n,)`.

    The raster is padded to a canonical shape (`shapes.raster_shape`, with the NGNEM's
    `tiling`) and the points to a canonical capacity: a handful of programs per machine."""
    h, w = vox.shape
    rows, cols = raster_shape((h, w), vox.cell_m, tiling)
    surface = np.zeros((rows, cols), np.float32)
    valid = np.zeros((rows, cols), bool)
    flat_s, flat_v = np.zeros(h * w, np.float32), np.zeros(h * w, bool)
    flat_s[nodes.cell] = nodes.z_surface
    flat_v[nodes.cell] = True
    surface[rows - h:, :w] = flat_s.reshape(h, w)                   # the data in the south-west corner
    valid[rows - h:, :w] = flat_v.reshape(h, w)
    n = len(points)
    padded = np.zeros((canonical_capacity(n), 3), np.float32)
    padded[:n] = points
    threshold_m = threshold_m if isinstance(threshold_m, jax.Array) else np.float32(threshold_m)
    out = programs.height_test(surface, valid, np.asarray([h, w], np.int32), padded, np.float32(vox.cell_m),
                               threshold_m)
    return np.asarray(out)[:n]


def extract_ground(points: np.ndarray, vox: Voxels, object_cell: np.ndarray, in_ndng: np.ndarray, config: Config,
                   params: Params, *, points_tree: cKDTree | None = None,
                   tiling: Tiling | None = None) -> tuple[SupportNodes, np.ndarray, int]:
    """Step 7 (Sec. 2.6) as `config` reads it: support nodes, then the final rule.

    Args:
      points: the local coordinates `vox` was binned from, float64 `(n, 3)` metres.
      vox, object_cell, in_ndng: as for `support_nodes`.
      config: `v1`, `fill_neighbours`, `support_z`, `support_elevation`, `final_rule`.
      params: the height rule's threshold (`Params.threshold_m(W)`).
      points_tree: a `cKDTree` of `points`, reused if given.
      tiling: the NGNEM's tiling (it sets the support surface's padded shape).

    Returns: `(nodes, ground bool (n,), M)`; M = 0 when the M-nearest rule is not used.
    """
    own_z = column_lowest_z(points, vox) if config.support_elevation == "lowest" else None
    nodes = support_nodes(vox, object_cell, in_ndng, v1=config.v1, fill_neighbours=config.fill_neighbours,
                          support_z=config.support_z, own_z=own_z)
    ground, m_points = np.ones(len(points), bool), 0
    if config.final_rule in ("m_nearest", "both"):
        ground, m_points = m_nearest_ground(points, nodes, points_tree=points_tree)
    if config.final_rule in ("height", "both"):
        host = jax.tree.map(np.asarray, params)           # numpy arithmetic: no tiny JAX programs
        ground = ground & height_ground(points, nodes, vox, host.threshold_m(vox.cell_m), tiling)
    return nodes, ground, m_points
