"""DMF step 7: GF-support nodes and the final point rule (Wu et al. 2025, Sec. 2.6).

Support nodes sit at the centres of the NGNEM cells that hold an ND_CE: TP_G on ground cells,
TPN on object cells (NGNEM_RC). A TP_G whose column's ND_CE is in ND_NG takes that node's
elevation; every other node takes the mean of its `fill_neighbours` (24) nearest such TP_G
(2D). All nodes are lowered by `v1 * W`. A node's own elevation is its ND_CE's (the centroid of
the column's lowest voxel, the paper) or, as a reading (R), the column's lowest point
(`column_lowest`); it is measured where those points are, and (R) carried from there to the
cell centre along the local plane (`carry_to_centres`). Host part: the KD-tree queries
(scipy). The per-point bookkeeping is jitted JAX (`gfjax.dmf.programs`).

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

__all__ = ["extract_ground", "SupportNodes", "support_nodes", "column_lowest", "carry_to_centres", "m_nearest_ground",
           "height_ground"]

# A plane fit whose normal matrix has a determinant below this share of the product of its
# diagonal is degenerate (neighbours on a line): its node keeps its elevation.
_DEGENERATE = 1e-6
_BAND_ROWS = 256          # raster rows whose window sums are held at once (a large raster's memory)


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


def column_lowest(points: np.ndarray, vox: Voxels) -> np.ndarray:
    """The lowest point of each ND_CE's column (so of its lowest voxel), float64 `(m, 3)` [m]
    (of equally low points, one).

    Args:
      points: the local coordinates `vox` was binned from, float64 `(n, 3)` metres.
      vox: voxel columns (`bin_voxels(points, W)`).
    """
    h, w = vox.shape
    lowest = np.full(h * w, np.inf)
    np.minimum.at(lowest, vox.point_cell, points[:, 2])
    at_lowest = np.flatnonzero(points[:, 2] == lowest[vox.point_cell])
    which = np.zeros(h * w, np.int64)
    which[vox.point_cell[at_lowest]] = at_lowest
    return points[which[vox.cell]]


def carry_to_centres(z: np.ndarray, xy: np.ndarray, vox: Voxels, known: np.ndarray) -> np.ndarray:
    """Elevations measured at `xy` carried to the centres of their cells (R,
    `Config.support_position="centroid"`).

    A node's own elevation is that of its ND_CE centroid (or its column's lowest point), so it
    holds where those points are, not at the cell centre: on a slope the lowest voxel holds the
    downhill part of the cell, and the centroid lies downhill of the centre and below the
    ground there (samp52, W = 4 m: 0.57 m below on average where the slope exceeds 0.6, 2.2 m
    at the 5th percentile; at the centroid's own x, y 0.05 m). Each known node moves along the
    least-squares plane through the known nodes of its 3x3 cells (itself included, each at its
    own x, y), clamped to their elevation range: a plane is carried exactly, and a fit tilted
    by a node left on an object moves no node past its neighbours. A node with fewer than
    three known neighbours, or neighbours on a line, keeps its elevation.

    Args:
      z: each node's elevation, float64 `(m,)` [m].
      xy: where it was measured, float64 `(m, 2)`, local metres.
      vox: the voxel columns (the nodes' cells, `vox.cell`).
      known: the nodes whose elevation is their own, bool `(m,)`; the others come back as they are.

    Returns: float64 `(m,)` [m].
    """
    h, w = vox.shape
    cell_m = vox.cell_m
    nodes = np.flatnonzero(known)
    cell = vox.cell[nodes]                                       # increasing, so rows are too
    row, col = cell // w, cell % w
    # Each known node on a raster one cell wider: its offset from its cell centre, its elevation.
    offset_x, offset_y = np.zeros((h + 2, w + 2), np.float32), np.zeros((h + 2, w + 2), np.float32)
    height, has = np.zeros((h + 2, w + 2)), np.zeros((h + 2, w + 2), bool)
    offset_x[row + 1, col + 1] = xy[nodes, 0] - (col + 0.5) * cell_m
    offset_y[row + 1, col + 1] = xy[nodes, 1] - (h - 1 - row + 0.5) * cell_m
    height[row + 1, col + 1] = z[nodes]
    has[row + 1, col + 1] = True
    out = np.array(z, dtype=np.float64)
    for top in range(0, h, _BAND_ROWS):
        bottom = min(h, top + _BAND_ROWS)
        first, last = np.searchsorted(row, [top, bottom])
        if first < last:
            band = slice(first, last)
            out[nodes[band]] = _carried_band(offset_x, offset_y, height, has, top, bottom, row[band] - top, col[band],
                                             z[nodes[band]], cell_m)
    return out


def _carried_band(offset_x, offset_y, height, has, top: int, bottom: int, row, col, z, cell_m: float) -> np.ndarray:
    """`carry_to_centres` for the nodes of raster rows `top:bottom` (at `row` within the band,
    `col`, elevations `z`), from the padded rasters of offsets, elevations and presence."""
    w = has.shape[1] - 2
    rows = bottom - top
    middle = height[1 + top:1 + bottom, 1:w + 1]
    # Sums over the 3x3 cells of each cell: x and y from the centre of the middle cell, z from its elevation.
    n, sx, sy, sz, sxx, syy, sxy, sxz, syz = (np.zeros((rows, w)) for _ in range(9))
    low, high = np.full((rows, w), np.inf), np.full((rows, w), -np.inf)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            window = (slice(1 + top + dr, 1 + bottom + dr), slice(1 + dc, w + 1 + dc))
            m = has[window]
            u = np.where(m, offset_x[window] + dc * cell_m, 0.0)
            v = np.where(m, offset_y[window] - dr * cell_m, 0.0)
            dz = np.where(m, height[window] - middle, 0.0)
            n += m
            sx += u
            sy += v
            sz += dz
            sxx += u * u
            syy += v * v
            sxy += u * v
            sxz += u * dz
            syz += v * dz
            low = np.minimum(low, np.where(m, height[window], np.inf))
            high = np.maximum(high, np.where(m, height[window], -np.inf))
    n, sx, sy, sz = n[row, col], sx[row, col], sy[row, col], sz[row, col]
    cxx = sxx[row, col] - sx * sx / n
    cyy = syy[row, col] - sy * sy / n
    cxy = sxy[row, col] - sx * sy / n
    cxz = sxz[row, col] - sx * sz / n
    cyz = syz[row, col] - sy * sz / n
    det = cxx * cyy - cxy * cxy
    fit = (n >= 3) & (det > _DEGENERATE * cxx * cyy)
    det = np.where(fit, det, 1.0)
    gx = np.where(fit, (cyy * cxz - cxy * cyz) / det, 0.0)
    gy = np.where(fit, (cxx * cyz - cxy * cxz) / det, 0.0)
    carried = z - gx * offset_x[1 + top + row, 1 + col] - gy * offset_y[1 + top + row, 1 + col]
    return np.clip(carried, low[row, col], high[row, col])


def support_nodes(vox: Voxels, object_cell: np.ndarray, in_ndng: np.ndarray, *, v1: float,
                  fill_neighbours: int, support_z: str = "ndng", support_position: str = "centroid",
                  own: np.ndarray | None = None) -> SupportNodes:
    """Build the GF-support node layer (Sec. 2.6, first two paragraphs).

    Args:
      vox: voxel columns (`bin_voxels`).
      object_cell: NGNEM_RC per flat cell, bool `(h * w,)`.
      in_ndng: ND_CE index is in ND_NG, bool `(m,)`.
      v1: lowering factor (paper: 2); fill_neighbours: 24 in the paper.
      support_z: (R) "ndng": a TP_G keeps its own elevation only when its column's ND_CE is
        in ND_NG (the paper); "ndce": every TP_G keeps its column's ND_CE elevation.
      support_position: (R) "centre": a node's own elevation is its cell centre's (the paper);
        "centroid": it is carried there from where it was measured (`carry_to_centres`).
      own: where each node's own elevation is measured, float64 `(m, 3)` local [m] (default:
        the ND_CE centroid, the paper; `column_lowest` for `support_elevation="lowest"`).

    Returns: `SupportNodes`.
    """
    h, w = vox.shape
    cell_m = vox.cell_m
    row, col = vox.cell // w, vox.cell % w
    x = (col + 0.5) * cell_m
    y = (h - 1 - row + 0.5) * cell_m
    ground = ~object_cell[vox.cell]
    known = ground & in_ndng if support_z == "ndng" else ground
    own = vox.centroid if own is None else own
    z = np.array(own[:, 2], dtype=np.float64)
    if support_position == "centroid":
        z = carry_to_centres(z, own[:, :2], vox, known)
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
      config: `v1`, `fill_neighbours`, `support_z`, `support_elevation`, `support_position`,
        `final_rule`.
      params: the height rule's threshold (`Params.threshold_m(W)`).
      points_tree: a `cKDTree` of `points`, reused if given.
      tiling: the NGNEM's tiling (it sets the support surface's padded shape).

    Returns: `(nodes, ground bool (n,), M)`; M = 0 when the M-nearest rule is not used.
    """
    own = column_lowest(points, vox) if config.support_elevation == "lowest" else None
    nodes = support_nodes(vox, object_cell, in_ndng, v1=config.v1, fill_neighbours=config.fill_neighbours,
                          support_z=config.support_z, support_position=config.support_position, own=own)
    ground, m_points = np.ones(len(points), bool), 0
    if config.final_rule in ("m_nearest", "both"):
        ground, m_points = m_nearest_ground(points, nodes, points_tree=points_tree)
    if config.final_rule in ("height", "both"):
        host = jax.tree.map(np.asarray, params)           # numpy arithmetic: no tiny JAX programs
        ground = ground & height_ground(points, nodes, vox, host.threshold_m(vox.cell_m), tiling)
    return nodes, ground, m_points
