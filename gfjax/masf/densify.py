"""Multiscale TIN densification (Cao et al. 2024, Sec. 2.4, Fig. 6; SPEC 4.4). Host numpy + scipy.

1. The points of the top layer are the seeds of a 2D TIN, with simulated ground points at the
   centres of a ring of buffer cells around the grid (z of the nearest top-layer point), so
   every point lies inside the TIN and no long thin triangles form at its edge. Seeds that
   form pits in the seed TIN (`low_seed_pits`, our addition) are dropped first. Before each
   lower layer and before the last test, the buffer points may take new heights from the
   ground found so far (`buffer_heights`, R): with the paper's fixed heights, a slope that
   rises to the edge of the cloud meets a flat TIN pinned at the height of the nearest
   top-layer point, often metres lower, and its ground near the edge is rejected.
2. For each lower layer k, its points not yet ground whose perpendicular distance to the facet
   under them is below `DT_k = st * alpha_k + ft_m` (Eq. 2) become ground; they are all tested
   against the TIN of the previous layers, then inserted together. With `layer_passes > 1`
   the layer's remaining points are tested again against the TIN that now holds them, until
   a pass adds none (R: classic TIN densification inserts accepted points at once, so the TIN
   climbs ridges and terrace edges within a layer; each point is still accepted only once).
   The TIN is triangulated once (Qhull) and then grows by batch insertion
   (`GroundTin.insert`): only the triangles whose circumcircle holds an accepted point change,
   and a retest measures again only the points over a changed triangle (the others' distance
   is the same), so extra passes cost a small fraction of a re-triangulation. In general
   position the labels equal those of re-triangulating everything before each pass (test).
   With `mirror_max_m` (R), a point within that distance of the TIN is also accepted when its
   mirror image through the nearest corner of the facet under it is within DT_k
   (`GroundTin.mirrored`, Axelsson 2000): the TIN of a coarse layer cuts across ridges and the
   upper edges of terraces, and the ground there, revealed only by the small balls of the last
   layers, stands above it by more than their small DT. Only points that joined by their own
   distance are centres, so the test never follows a flat object from point to point.
3. Finally every remaining point of the whole cloud closer than `ft_m` to the TIN is ground.
"""
from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from gfjax.masf.config import BUFFER_HEIGHTS
from gfjax.masf.ground_tin import GroundTin
from gfjax.masf.tin import nearest_z

__all__ = ["Densified", "BUFFER_HEIGHTS", "BUFFER_MAX_SLOPE", "buffer_cells", "buffer_z", "densify"]

# The steepest slope "extrapolated" carries out to a buffer point (rise over run): a vertex
# whose facets span a data gap can have a slope that, carried a few metres, lifts the edge of
# the TIN onto objects. 1 (45 degrees) changed no label on the ISPRS training samples.
BUFFER_MAX_SLOPE = 1.0


class Densified(NamedTuple):
    """Outcome of the densification.

    Attributes:
      ground: bool `(n,)` over the points given to `densify`.
      seed_ground: bool `(p,)`, potential ground points that joined the TIN in some layer.
      added_per_layer: int64 `(L,)`, potential ground points that joined at each layer (the
        top layer's seeds first).
      tin_rebuilds: insertions that fell back to a full re-triangulation (co-circular ties).
    """

    ground: np.ndarray
    seed_ground: np.ndarray
    added_per_layer: np.ndarray
    tin_rebuilds: int


def buffer_cells(shape: tuple[int, int], *, cell_m: float) -> np.ndarray:
    """x, y of the centres of the ring of cells just outside an `(h, w)` grid, float64 `(r, 2)`."""
    h, w = shape
    cols = np.arange(-1, w + 1)
    rows_y = np.arange(0, h)
    south = np.stack([(cols + 0.5) * cell_m, np.full(len(cols), -0.5 * cell_m)], axis=1)
    north = np.stack([(cols + 0.5) * cell_m, np.full(len(cols), (h + 0.5) * cell_m)], axis=1)
    west = np.stack([np.full(h, -0.5 * cell_m), (rows_y + 0.5) * cell_m], axis=1)
    east = np.stack([np.full(h, (w + 0.5) * cell_m), (rows_y + 0.5) * cell_m], axis=1)
    return np.concatenate([south, north, west, east])


def buffer_z(tin: GroundTin, ring: np.ndarray, *, extrapolate: bool) -> np.ndarray:
    """Heights of the buffer points `ring` (int64 `(r,)` vertex ids of `tin`) from the ground
    points of the TIN (every other vertex): the z of the nearest one in x, y, plus with
    `extrapolate` its slope times the offset, the slope at most `BUFFER_MAX_SLOPE`.

    The slope at a vertex is the area-weighted mean gradient of its facets that hold no buffer
    point; a nearest vertex without such a facet (a corner of the ground points) takes the slope
    of the nearest vertex with one (zero when there is none). Returns float64 `(r,)` [m].
    """
    from scipy.spatial import cKDTree

    is_ring = np.zeros(len(tin.xyz_m), dtype=bool)
    is_ring[ring] = True
    ground = np.flatnonzero(~is_ring)
    ring_xy = tin.xyz_m[ring, :2]
    _, near = cKDTree(tin.xyz_m[ground, :2]).query(ring_xy, k=1)
    vertex = ground[near]
    z = tin.xyz_m[vertex, 2]
    if not extrapolate:
        return z
    facets = tin.simplices[~is_ring[tin.simplices].any(axis=1)]
    corners = tin.xyz_m[facets]                                                   # (t, 3, 3)
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    area = 0.5 * np.abs(normal[:, 2])              # counter-clockwise facets: normal z > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        grad = -normal[:, :2] / normal[:, 2:3]
    grad = np.where(area[:, None] > 0, grad, 0.0)
    n = len(tin.xyz_m)
    weight = np.bincount(facets.reshape(-1), np.repeat(area, 3), minlength=n)
    slope = np.stack([np.bincount(facets.reshape(-1), np.repeat(area * grad[:, j], 3), minlength=n)
                      for j in range(2)], axis=1)
    sloped = np.flatnonzero(weight > 0)
    if len(sloped) == 0:
        return z
    _, near = cKDTree(tin.xyz_m[sloped, :2]).query(tin.xyz_m[vertex, :2], k=1)
    slope = slope[sloped[near]] / weight[sloped[near], None]
    offset = ring_xy - tin.xyz_m[vertex, :2]
    reach = np.hypot(offset[:, 0], offset[:, 1])
    rise = np.clip(np.einsum("rk,rk->r", slope, offset), -BUFFER_MAX_SLOPE * reach, BUFFER_MAX_SLOPE * reach)
    return z + rise


def low_seed_pits(xyz_m: np.ndarray, *, drop_m: float, slope: float, cap_m: float) -> np.ndarray:
    """Top-layer seeds that form pits in the seed TIN: low outliers the preprocessing missed.

    Seeds joined by an edge of their 2D Delaunay TIN are linked when their z differ by at most
    `drop_m + slope * edge length`; a connected group, smaller than half the seeds, all of
    whose other edges climb, is a pit of low outliers (multipath patches metres below the
    ground, as in ISPRS samp41). The seeds are ground points of a large-alpha layer, so roofs
    and canopy, which make yards and forest floor look like pits among all cells, are absent.

    Args:
      xyz_m: float64 `(s, 3)` seeds, local metres.

    Returns:
      bool `(s,)`, seeds to drop.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import Delaunay, QhullError

    pits = np.zeros(len(xyz_m), dtype=bool)
    if len(xyz_m) < 4:
        return pits
    try:
        simplices = Delaunay(xyz_m[:, :2]).simplices
    except (QhullError, ValueError):
        return pits
    edges = np.concatenate([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    head, tail = edges[:, 0], edges[:, 1]
    rise = xyz_m[tail, 2] - xyz_m[head, 2]
    length = np.linalg.norm(xyz_m[tail, :2] - xyz_m[head, :2], axis=1)
    linked = np.abs(rise) <= drop_m + slope * np.minimum(length, cap_m)
    graph = coo_matrix((np.ones(int(linked.sum()), dtype=np.int8), (head[linked], tail[linked])),
                       shape=(len(xyz_m), len(xyz_m)))
    _, label = connected_components(graph, directed=False)
    size = np.bincount(label)
    across = label[head] != label[tail]
    has_down = np.zeros(len(size), dtype=bool)
    has_up = np.zeros(len(size), dtype=bool)
    up = rise > 0
    has_up[label[head[across & up]]] = True
    has_down[label[tail[across & up]]] = True
    has_up[label[tail[across & ~up]]] = True
    has_down[label[head[across & ~up]]] = True
    pit = has_up & ~has_down & (2 * size < len(xyz_m))
    return pit[label]


def densify(points_m: np.ndarray, seeds: np.ndarray, layers: np.ndarray, alphas_m: np.ndarray, *,
            shape: tuple[int, int], cell_m: float, st: float, ft_m: float,
            pit_drop_m: float = 1.0, pit_slope: float | None = 1.0, pit_cap_m: float = 4.0,
            nearest_facet: bool = False, layer_passes: int = 3, retest_earlier: bool = False,
            retriangulate: bool = False, buffer_heights: str = "top", mirror_max_m: float | None = None, step: Callable[[str], None] = lambda name: None) -> Densified:
    """Label ground points by top-down densification of the layer TINs.

    Args:
      points_m: float64 `(n, 3)` local metres, every point the filter uses.
      seeds: int64 `(p,)` indices into `points_m` of the potential ground points.
      layers: bool `(L, p)`, layer membership of the potential ground points, top layer first.
      alphas_m: float64 `(L,)` the layers' alpha [m].
      shape: `(h, w)` of the preprocessing grid; cell_m its cell [m].
      st: slope threshold ST [-]; ft_m: final threshold FT [m] (Eq. 2).
      pit_drop_m, pit_slope, pit_cap_m: the seed pit test (`low_seed_pits`; slope None: off).
      nearest_facet: distance to the nearest facet instead of the facet under the point.
      layer_passes: most tests of a layer's remaining points, each against the TIN with the
        points the previous pass accepted, stopping early when a pass accepts none (1: one
        test per layer).
      retest_earlier: at each layer, also retest the points of earlier layers that are not yet
        ground, each with the DT of the first layer that held it (no extra triangulation).
      retriangulate: the reference path: triangulate the TIN again with Qhull after each pass
        instead of inserting the accepted points, and retest every waiting point.
      buffer_heights: one of `BUFFER_HEIGHTS`: the buffer points' heights, fixed from the top
        layer ("top") or taken again from the TIN's ground points before each lower layer and
        before the last test (`buffer_z`).
      mirror_max_m: a layer's point closer than this to the TIN [m] is accepted too when its
        mirror image through the nearest corner of the facet under it is closer than DT_k
        (`GroundTin.mirrored`); the centre is a seed or a point that joined by its own
        distance, never a buffer point or one that joined through its image. None: no mirror
        test. The last test of the whole cloud takes the distance alone.
      step: told when each layer below the top one, and then the labelling, is done
        (`n_layers` calls; a progress bar).
    """
    if buffer_heights not in BUFFER_HEIGHTS:
        raise ValueError(f"buffer_heights must be one of {BUFFER_HEIGHTS}, got {buffer_heights!r}")
    n_layers, n_seeds = layers.shape
    seed_xyz = points_m[seeds]
    in_tin = layers[0].copy() if n_layers else np.zeros(n_seeds, dtype=bool)
    if pit_slope is not None and in_tin.any():
        top = np.flatnonzero(in_tin)
        in_tin[top[low_seed_pits(seed_xyz[top], drop_m=pit_drop_m, slope=pit_slope, cap_m=pit_cap_m)]] = False
    if not in_tin.any():
        in_tin[:] = True          # no top layer (degenerate input): every seed is a seed
    added = np.zeros(max(n_layers, 1), dtype=np.int64)
    added[0] = np.count_nonzero(in_tin)
    ring_xy = buffer_cells(shape, cell_m=cell_m)
    ring = np.column_stack([ring_xy, nearest_z(ring_xy, seed_xyz[in_tin])])
    # threshold_m[i]: DT of the first (largest-alpha) layer that held seed i; pits start over
    threshold_m = np.full(n_seeds, -np.inf)
    if n_layers:
        threshold_m[layers[0] & in_tin] = st * alphas_m[0] + ft_m
    tin = GroundTin(np.concatenate([seed_xyz[in_tin], ring]))
    ring_ids = np.count_nonzero(in_tin) + np.arange(len(ring))       # insertions keep vertex ids

    def lift(tin: GroundTin) -> GroundTin:
        if buffer_heights == "top":
            return tin
        return tin.with_heights(ring_ids, buffer_z(tin, ring_ids, extrapolate=buffer_heights == "extrapolated"))

    # centres[v]: TIN vertex v may be a mirror's centre: a seed, or a point that joined by its
    # own distance; not a buffer point, nor one that joined through its image (else a flat
    # object whose edge got in would be followed point by point: a roof, a bridge deck)
    centres = np.ones(len(tin.xyz_m), dtype=bool)
    centres[ring_ids] = False

    def measure(tin: GroundTin, xyz_m: np.ndarray, start: np.ndarray | None = None):
        """Distance to `tin` (the smaller of the point's and its mirror image's, see
        `mirror_max_m`), the facet under the point, the one under its image (-1: none) and
        the point's own distance."""
        own_m, facet = tin.measure(xyz_m, nearest_facet=nearest_facet, start=start)
        distance_m = own_m.copy()
        image_facet = np.full(len(xyz_m), -1, dtype=np.int64)
        if mirror_max_m is not None:
            near = np.flatnonzero(own_m < mirror_max_m)
            image_m, image_facet[near] = tin.mirrored(xyz_m[near], facet[near], centres, nearest_facet=nearest_facet)
            distance_m[near] = np.minimum(own_m[near], image_m)
        return distance_m, facet, image_facet, own_m

    def touched(old: GroundTin, changed: np.ndarray, facet: np.ndarray) -> np.ndarray:
        """Where `facet` (or, for `nearest_facet`, an edge neighbour) was replaced."""
        hit = (facet >= 0) & changed[np.maximum(facet, 0)]
        if nearest_facet:
            around = old.neighbours[np.maximum(facet, 0)]
            hit |= (facet >= 0) & (changed[np.maximum(around, 0)] & (around >= 0)).any(axis=1)
        return hit

    for level in range(1, n_layers):
        tin = lift(tin)
        dt_m = st * alphas_m[level] + ft_m
        fresh = layers[level] & ~np.isfinite(threshold_m)
        threshold_m[fresh] = dt_m
        waiting = (np.isfinite(threshold_m) if retest_earlier else layers[level]) & ~in_tin
        candidates = np.flatnonzero(waiting)
        limit_m = threshold_m[candidates] if retest_earlier else np.full(len(candidates), dt_m)
        distance_m, facet, image_facet, own_m = measure(tin, seed_xyz[candidates])
        for pass_ in range(layer_passes):
            accept = distance_m < limit_m
            if not accept.any():
                break
            old, keep = tin, ~accept
            tin, changed = old.insert(seed_xyz[candidates[accept]], facet[accept], retriangulate=retriangulate)
            centres = np.concatenate([centres, own_m[accept] < limit_m[accept]])
            in_tin[candidates[accept]] = True
            added[level] += np.count_nonzero(accept)
            candidates, limit_m, distance_m, own_m = candidates[keep], limit_m[keep], distance_m[keep], own_m[keep]
            facet, image_facet = facet[keep], image_facet[keep]
            if pass_ + 1 == layer_passes:
                break
            # Only points over a replaced triangle (or next to one, for nearest_facet), or whose
            # mirror image is, can change.
            stale = touched(old, changed, facet) | touched(old, changed, image_facet)
            start = tin.vertex_to_simplex[old.simplices[facet[stale], 0]]
            distance_m[stale], facet[stale], image_facet[stale], own_m[stale] = measure(tin, seed_xyz[candidates[stale]], start)
        step(f"layer {level + 1} of {n_layers}")
    tin = lift(tin)
    ground = np.zeros(len(points_m), dtype=bool)
    ground[seeds[in_tin]] = True
    rest = np.flatnonzero(~ground)
    if len(rest):
        ground[rest[tin.distance_m(points_m[rest], nearest_facet=nearest_facet) < ft_m]] = True
    step("every point")
    return Densified(ground, in_tin, added, tin.rebuilds)
