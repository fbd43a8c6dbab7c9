"""DMF raster stages (steps 4-6 of SPEC section 3): NGNEM -> R_HC -> NGNEM_BI -> NGNEM_RC.

Wu et al. (2025), Sec. 2.4 (Eqs. 2-4) and Sec. 2.5, on one tile; `jax.vmap` batches tiles.
Every kernel is from `gfjax.raster` except the equal-layer regions (labelled on a 2x grid
whose in-between cells say "same layer") and the per-group segment statistics.

Padding: `inside` marks the tile's real cells (a top-left block when the tile is padded to a
batch shape). Nothing outside `inside` is ever read as data: the max filter and the closing
ignore it, patch borders are those of `inside`, labels never cross it. So a padded tile gives
the same rasters on its inside cells as the unpadded tile (tested).

Readings (SPEC 3.5, R): the holes of patches that enclose them jointly are tested as one group
(for one enclosing patch this is exactly the per-patch hole filling: the group is the patch,
the cells it encloses, and any patch nested inside); patches of the same closing size are closed
together; Eq. 4 closes a patch that touches one or two borders against a wall just beyond them.
"""
from __future__ import annotations

import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import Labels, Mask, Raster
from gfjax.raster import (
    boundary_ring,
    fill_holes,
    label_components,
    max_filter,
    nearest_valid_index,
    relabel_consecutive,
)
from gfjax.raster.label import shift

__all__ = ["RasterStages", "raster_stages", "fill_ngnem", "rhc", "coverage", "equal_layer_regions",
           "patch_correction", "closing_square", "dilate_square", "WALL_COMBOS"]

_SIDES = ("north", "south", "west", "east")
# Eq. 4 (R): walls for a patch touching one or two borders; index 0 = no wall.
WALL_COMBOS: tuple[tuple[int, ...], ...] = ((),) + tuple((i,) for i in range(4)) + tuple(itertools.combinations(range(4), 2))


class RasterStages(NamedTuple):
    """Rasters of one tile, shape `(h, w)` each (row 0 = north).

    Attributes:
      ngnem: near-ground node elevation model, empty cells filled from the nearest valid cell [m]
        (0 outside `inside`).
      layer: voxel layer index k of each cell, filled likewise, int32.
      rhc: R_HC of Eq. 2 (the 5x5 max filter exceeds the cell by more than W).
      ngnem_bi: NGNEM_BI: cells covered by non-ground objects (Sec. 2.4).
      ngnem_rc0: NGNEM_RC after the equal-layer correction (Sec. 2.5, first part).
      ngnem_rc: NGNEM_RC after the boundary-ring correction: the object cells.
      instances: object instance id per cell, 1..n in raster order, 0 = ground, int32.
      converged: every bounded labelling loop converged, bool scalar.
    """

    ngnem: Raster
    layer: Labels
    rhc: Mask
    ngnem_bi: Mask
    ngnem_rc0: Mask
    ngnem_rc: Mask
    instances: Labels
    converged: Bool[Array, ""]


def fill_ngnem(z: Raster, layer: Labels, valid: Mask, inside: Mask) -> tuple[Raster, Labels]:
    """NGNEM and layer rasters with empty cells taken from the nearest valid cell (SPEC 3.4);
    zero outside `inside` (the padding, which no stage reads, costs no search)."""
    index, _ = nearest_valid_index(valid, inside)
    src = jnp.maximum(index, 0).reshape(-1)
    has = (index >= 0) & inside
    zf = jnp.where(has, z.reshape(-1)[src].reshape(z.shape), jnp.zeros((), z.dtype))
    kf = jnp.where(has, layer.reshape(-1)[src].reshape(layer.shape), jnp.zeros((), layer.dtype))
    return zf, kf


def rhc(ngnem: Raster, inside: Mask, cell_m: Float[Array, ""], *, radius_px: int) -> Mask:
    """Eq. 2: `R_HC = maxfilter(NGNEM) - NGNEM > W` with a square of side `2 radius_px + 1`."""
    top = max_filter(ngnem, inside, radius_px=radius_px, footprint="square")
    return inside & (top - ngnem > cell_m)


def _dilate_line(x: Mask, r: Int[Array, ""], axis: int, max_r: int) -> Mask:
    """Binary dilation along one axis with half-width `r` (traced, `<= max_r`): a window sum
    of prefix sums, O(1) per cell for any r. Beyond the raster counts as False."""
    n = x.shape[axis]
    pad = [(0, 0), (0, 0)]
    pad[axis] = (max_r + 1, max_r)
    prefix = jnp.cumsum(jnp.pad(x.astype(jnp.int32), pad), axis=axis)   # prefix[t] = sum x_pad[:t]
    upper = lax.dynamic_slice_in_dim(prefix, max_r + r + 1, n, axis=axis)
    lower = lax.dynamic_slice_in_dim(prefix, max_r - r, n, axis=axis)
    return upper - lower > 0


def dilate_square(x: Mask, r: Int[Array, ""], *, max_radius_px: int) -> Mask:
    """Binary dilation by the `(2r+1)^2` square, r traced (`<= max_radius_px`)."""
    return _dilate_line(_dilate_line(x, r, 1, max_radius_px), r, 0, max_radius_px)


def closing_square(mask: Mask, inside: Mask, r: Int[Array, ""], *, max_radius_px: int) -> Mask:
    """Binary closing by the `(2r+1)^2` square ignoring cells outside `inside` (they and the
    space beyond the raster are the identity of each step), restricted to `inside`.

    Equals `gfjax.raster.closing(mask, inside, radius_px=r, footprint="square")` on `inside`
    (tested), with r traced so one compile serves every half-width (Eq. 3).
    """
    dilated = dilate_square(mask & inside, r, max_radius_px=max_radius_px)
    return inside & ~dilate_square(~dilated & inside, r, max_radius_px=max_radius_px)


def _segment(values, ids, num, op):
    return op(values.reshape(-1), ids.reshape(-1), num_segments=num)


def _group_test(groups: Labels, edge: Mask, fill: Mask, ngnem: Raster) -> tuple[Mask, Bool[Array, " g"]]:
    """Per group: `H_fill = mean NGNEM over fill cells >= H_edge = max over edge cells`.

    Returns: the fill cells of passing groups, and per group id "has fill cells".
    """
    num = groups.size + 1
    h_edge = _segment(jnp.where(edge, ngnem, -jnp.inf), groups, num, jax.ops.segment_max)
    n_fill = _segment(fill.astype(jnp.int32), groups, num, jax.ops.segment_sum)
    s_fill = _segment(jnp.where(fill, ngnem, 0), groups, num, jax.ops.segment_sum)
    h_fill = s_fill / jnp.maximum(n_fill, 1).astype(ngnem.dtype)
    passed = (n_fill > 0) & (h_fill >= h_edge)
    return fill & passed[groups], n_fill > 0


def _hole_test(edge: Mask, fill: Mask, ngnem: Raster) -> tuple[Mask, Bool[Array, ""]]:
    """Per hole (R, `hole_test="hole"`): each 4-connected fill region passes when its mean
    NGNEM >= the maximum NGNEM of the enclosing patch cells on its one-cell ring."""
    units, conv = label_components(fill, connectivity=4)
    ring = boundary_ring(units, ngnem, edge, num_labels=units.size, connectivity=8)
    num = units.size + 1
    n_fill = _segment(fill.astype(jnp.int32), units, num, jax.ops.segment_sum)
    h_fill = _segment(jnp.where(fill, ngnem, 0), units, num, jax.ops.segment_sum) / jnp.maximum(n_fill, 1).astype(ngnem.dtype)
    passed = (n_fill > 0) & (h_fill >= ring.max)
    return fill & passed[units], conv


def _side_masks(inside: Mask) -> tuple[Mask, Mask, Mask, Mask]:
    """Cells of `inside` on its north, south, west, east border."""
    return (inside & ~shift(inside, -1, 0, False), inside & ~shift(inside, 1, 0, False),
            inside & ~shift(inside, 0, -1, False), inside & ~shift(inside, 0, 1, False))


def _walls(sides_padded: tuple[Mask, ...]) -> tuple[Mask, ...]:
    """Frame cells just beyond each border side (coordinates with a one-cell frame)."""
    n, s, w, e = sides_padded
    return shift(n, 1, 0, False), shift(s, -1, 0, False), shift(w, 0, 1, False), shift(e, 0, -1, False)


def coverage(ngnem: Raster, patches: Mask, inside: Mask, *, max_close_px: int,
             border_patches: bool, hole_test: str, close_all: bool) -> tuple[Mask, Bool[Array, ""]]:
    """Ground coverage regions (Sec. 2.4): NGNEM_BI from the R_HC patches.

    1. Patches (8-connected R_HC) are sorted by the borders they touch: none or 3-4 -> plain
       hole filling; one or two (Eq. 4, R) -> hole filling against walls beyond those borders.
    2. Per class, the holes enclosed by its patches are grouped with the patches enclosing
       them; with `hole_test="patch"` (SPEC) a group passes when its holes' mean NGNEM >= the
       enclosing patches' max NGNEM, and its holes become 1 in NGNEM_BI; with "hole" (R) each
       hole is tested against the enclosing cells on its own ring.
    3. A patch with no hole is closed with a square of side `w = max(3, 2 floor(sqrt(N)/2)+1)`
       (Eq. 3, N its cell count; half-width capped at `max_close_px`), then tested the same
       way on the cells it adds. Patches of one half-width are closed together. With
       `close_all` (R) every patch is closed, holes or not (incomplete roof outlines inside
       a patch that has other holes).

    Returns: `(ngnem_bi, converged)`.
    """
    h, w = ngnem.shape
    labels, conv = label_components(patches, connectivity=8)
    num = h * w + 1
    sides = _side_masks(inside)
    touch = jnp.stack([_segment(s.astype(jnp.int32), labels, num, jax.ops.segment_max) > 0 for s in sides], axis=1)
    n_touch = jnp.sum(touch, axis=1, dtype=jnp.int32)
    code = jnp.sum(touch.astype(jnp.int32) * jnp.array([1, 2, 4, 8], jnp.int32)[None, :], axis=1)
    lookup = [0] * 16
    if border_patches:
        for c, combo in enumerate(WALL_COMBOS):
            if combo:
                lookup[sum(1 << i for i in combo)] = c
    combo_of_patch = jnp.where((n_touch >= 1) & (n_touch <= 2), jnp.asarray(lookup, jnp.int32)[code], 0)
    combo_cell = jnp.where(patches, combo_of_patch[labels], -1)

    # 1-2: hole filling per wall class (a `lax.map` over the classes).
    pad = functools.partial(jnp.pad, pad_width=1, constant_values=False)
    walls = _walls(tuple(pad(s) for s in sides))
    members = jnp.stack([combo_cell == c for c in range(len(WALL_COMBOS))])              # (c, h, w)
    wall_masks = jnp.stack([functools.reduce(jnp.logical_or, [walls[i] for i in combo], jnp.zeros((h + 2, w + 2), bool))
                            for combo in WALL_COMBOS])
    empty = jnp.zeros((h, w), bool)

    def fill_class(args):                     # classes without patches skip the work (lax.cond)
        member, wall = args

        def run(_):
            filled_p = fill_holes(pad(member) | wall)
            near_out = functools.reduce(jnp.logical_or, [shift(~filled_p, dr, dc, False)
                                                         for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1))])
            return filled_p[1:-1, 1:-1] & inside, member & near_out[1:-1, 1:-1]

        return lax.cond(jnp.any(member), run, lambda _: (empty, empty), None)

    filled, outer_cells = lax.map(fill_class, (members, wall_masks))
    outer_cell = jnp.any(outer_cells, axis=0)
    outer_patch = _segment(outer_cell.astype(jnp.int32), labels, num, jax.ops.segment_max) > 0
    edge = members & outer_patch[labels][None]
    fill = filled & ~edge

    def test_class(args):
        member, e, f, fl = args

        def run(_):
            if hole_test == "patch":
                groups, conv_g = label_components(fl, connectivity=8)
                return _group_test(groups, e, f, ngnem)[0], conv_g
            return _hole_test(e, f, ngnem)

        return lax.cond(jnp.any(member), run, lambda _: (empty, jnp.array(True)), None)

    marked, conv_g = lax.map(test_class, (members, edge, fill, filled))
    bi = jnp.any(marked, axis=0)
    # A patch with a hole (or nested in another's) touches a fill cell (3x3).
    near_fill = jax.vmap(lambda f: dilate_square(f, jnp.int32(1), max_radius_px=1))(filled & ~members)
    has_hole = _segment(jnp.any(members & near_fill, axis=0).astype(jnp.int32), labels, num, jax.ops.segment_max) > 0
    no_hole = patches & ~has_hole[labels]

    # 3: closing of the patches without holes, grouped by closing half-width (one scan step each).
    size = _segment(patches.astype(jnp.int32), labels, num, jax.ops.segment_sum)
    root = jnp.floor(jnp.sqrt(size.astype(jnp.float32))).astype(jnp.int32)
    root = root - (root * root > size).astype(jnp.int32) + ((root + 1) * (root + 1) <= size).astype(jnp.int32)
    radius = jnp.clip(root // 2, 1, max_close_px)
    radius_cell = jnp.where(no_hole | close_all, radius[labels], 0)

    def close_step(carry, r):
        bi_acc, conv_acc = carry
        source = radius_cell == r

        def run(_):
            closed_r = closing_square(source, inside, r, max_radius_px=max_close_px)
            if hole_test == "patch":
                groups_r, conv_r = label_components(closed_r, connectivity=8)
                return _group_test(groups_r, source, closed_r & ~source, ngnem)[0], conv_r
            return _hole_test(source, closed_r & ~source, ngnem)

        marked_r, conv_r = lax.cond(jnp.any(source), run, lambda _: (empty, jnp.array(True)), None)
        return (bi_acc | marked_r, conv_acc & conv_r), None

    radii = jnp.arange(1, max_close_px + 1, dtype=jnp.int32)
    (bi, conv_c), _ = lax.scan(close_step, (bi, jnp.all(conv_g)), radii)
    return bi & inside, conv & conv_c


def equal_layer_regions(layer: Labels, inside: Mask) -> tuple[Labels, Bool[Array, ""]]:
    """4-connected regions of equal layer index k (SPEC 3.6a: "patches of the same elevation").

    Labelled as the 4-connected components of a `(2h, 2w)` grid whose even cells are the
    raster's and whose odd cells join two neighbours with the same k.

    Returns: `(labels, converged)`, int32 `(h, w)`, 0 outside `inside`; a region's id is 1 +
    the row-major index of its first cell in the raster (`label_components`' convention on
    this raster, so ids stay below `h * w + 1`, the segment count of `patch_correction`).
    """
    h, w = layer.shape
    right = inside & shift(inside, 0, 1, False) & (layer == shift(layer, 0, 1, 0))
    down = inside & shift(inside, 1, 0, False) & (layer == shift(layer, 1, 0, 0))
    even = jnp.stack([inside, right], axis=-1).reshape(h, 2 * w)
    odd = jnp.stack([down, jnp.zeros_like(down)], axis=-1).reshape(h, 2 * w)
    grid = jnp.stack([even, odd], axis=1).reshape(2 * h, 2 * w)
    labels, conv = label_components(grid, connectivity=4)
    # A region's first cell on the grid is a raster cell (a joining cell comes after the cell
    # it joins), at grid index (2 r) (2 w) + 2 c: back to the raster's index r w + c.
    first = labels[0::2, 0::2] - 1
    return jnp.where(first >= 0, first // (4 * w) * w + first % (2 * w) // 2 + 1, 0), conv


def patch_correction(ngnem: Raster, layer: Labels, bi: Mask, inside: Mask,
                     min_share: Float[Array, ""] = 1.0) -> tuple[Mask, Mask, Labels, Bool[Array, ""]]:
    """Patch labelling correction (Sec. 2.5).

    (a) An equal-layer region is non-ground only if all its cells are 1 in NGNEM_BI (R: at
        least the share `min_share` of them; 1 = all, the paper); its NGNEM_BI cells stay 1.
    (b) A connected (8) non-ground region whose one-cell boundary ring has a maximum NGNEM above
        the region's mean NGNEM is ground (slope or depression) and is reset.

    Returns: `(rc0, rc, instances, converged)`; instances are 1..n in raster order.
    """
    h, w = ngnem.shape
    num = h * w + 1
    regions, conv_a = equal_layer_regions(layer, inside)
    in_bi = _segment(bi.astype(jnp.float32), regions, num, jax.ops.segment_sum)
    size = _segment(jnp.ones(regions.shape, jnp.float32), regions, num, jax.ops.segment_sum)
    enough = in_bi >= min_share * size                                   # min_share = 1: "all"
    rc0 = bi & inside & enough[regions]
    objects, conv_b = label_components(rc0, connectivity=8)
    ring = boundary_ring(objects, ngnem, inside, num_labels=h * w, connectivity=8)
    total = _segment(jnp.where(rc0, ngnem, 0), objects, num, jax.ops.segment_sum)
    count = _segment(rc0.astype(jnp.int32), objects, num, jax.ops.segment_sum)
    mean = total / jnp.maximum(count, 1).astype(ngnem.dtype)
    reset = ring.max > mean
    rc = rc0 & ~reset[objects]
    instances, _ = relabel_consecutive(jnp.where(rc, objects, 0))
    return rc0, rc, instances, conv_a & conv_b


@functools.partial(jax.jit, static_argnames=("max_filter_px", "max_close_px", "border_patches", "hole_test",
                                             "close_all"))
def raster_stages(z: Raster, layer: Labels, valid: Mask, inside: Mask, cell_m: Float[Array, ""],
                  rc_min_share: Float[Array, ""] = 1.0, *,
                  max_filter_px: int, max_close_px: int, border_patches: bool, hole_test: str,
                  close_all: bool) -> RasterStages:
    """Steps 4-6 of DMF on one tile (Wu et al. 2025, Sec. 2.3 end - 2.5).

    Args:
      z: ND_CE elevation per cell, float32 `(h, w)`, local metres; ignored where `~valid`.
      layer: ND_CE voxel layer index k per cell, int32 `(h, w)`.
      valid: cells holding an ND_CE, bool `(h, w)`.
      inside: the tile's real cells (`valid` is a subset), bool `(h, w)`.
      cell_m: W [m], float32 scalar (traced: one compile serves every W).
      rc_min_share: share of an equal-layer region that must be in NGNEM_BI (traced; 1 = all).
      max_filter_px, max_close_px, border_patches, hole_test, close_all: static options (`Config`; `max_close_px` is
        the largest closing half-width, `close_max_px // 2`).

    Returns: `RasterStages`; vmap over a batch of padded tiles.
    """
    ngnem, kf = fill_ngnem(z, layer, valid, inside)
    r = rhc(ngnem, inside, cell_m, radius_px=max_filter_px)
    bi, conv_bi = coverage(ngnem, r, inside, max_close_px=max_close_px, border_patches=border_patches,
                           hole_test=hole_test, close_all=close_all)
    rc0, rc, instances, conv_rc = patch_correction(ngnem, kf, bi, inside, rc_min_share)
    return RasterStages(ngnem=ngnem, layer=kf, rhc=r, ngnem_bi=bi, ngnem_rc0=rc0, ngnem_rc=rc,
                        instances=instances, converged=conv_bi & conv_rc)
