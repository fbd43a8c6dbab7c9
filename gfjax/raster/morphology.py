"""Grey morphology on masked rasters: min/max filters, opening, closing.

Footprints (static): `"disk"` of radius r = `skimage.morphology.disk(r)` (cells with
`dx^2 + dy^2 <= r^2`), `"square"` of radius r = `(2r + 1) x (2r + 1)` cells.

Masking: cells with `~valid`, and everything beyond the raster border, hold the identity of the
reduction (`+inf` for min, `-inf` for max; True/False on a bool raster), i.e.
`scipy.ndimage.grey_erosion(where(valid, z, inf), footprint=..., mode="constant", cval=inf)`.
Results are bit-identical to scipy (min and max only select values). A window holding no valid
cell gives the identity (`+inf` from `min_filter`, `-inf` from `max_filter`).

Fast forms (SPEC section 9), all exact, chosen by `algorithm` (static):
* square: separable, rows then columns, each a 1-D running min/max of half-width r.
* disk: the union of its row chords. For each row offset dy the chord half-width is
  `c(dy) = floor(sqrt(r^2 - dy^2))`; each distinct chord width gets one 1-D running min/max
  along rows, and the result is the reduction over dy of the chord rasters shifted by dy rows.
* disk of a traced radius (`max_radius_px` given; SMRF's progressive filter loops over its
  radii): one doubling table for the widest chord, `2 max_radius_px + 1`, then a loop over the
  `2r + 1` rows of the disk, each answered by two dynamic slices of the table. One small loop
  body serves every radius: SMRF's 18 openings of a 512-cell window compile in 0.3 s to a
  0.11 MB program that loads in 6 ms and runs in 24 ms, against 3.5 s, 2.7 MB, 309 ms and 92 ms
  unrolled (`experiments/results/progressive_program.md`); a fresh process pays the load.
* the 1-D running min/max: `"table"` (default) builds doubling levels
  `M_j[i] = max(x[i .. i + 2^j - 1])` once (log2(2r+1) passes) and answers every width with one
  comparison; `"vhgw"` is van Herk / Gil-Werman (3 comparisons per cell plus two block scans per
  width). Windows up to 5 cells use shifted comparisons. Both are O(1)-ish per cell and
  distinct width; on XLA CPU the table measured faster (experiments/raster_speed.py).

Used by SMRF (Pingel et al. 2013, progressive opening with disks), PMF (Zhang et al. 2003) and
DMF (Wu et al. 2025, Sec. 2.4: 5x5 max filter, patch closing).
"""
from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Int, Shaped

from gfjax._types import Mask
from gfjax.raster._window import SparseTable, pad_axis, running_direct, running_vhgw

Grey = Shaped[Array, "h w"]         # any dtype: heights, labels, flags (min/max need only an order)
Radius = int | Int[Array, ""]       # a static radius, or a traced one with a static `max_radius_px`

__all__ = [
    "disk", "chord_half_widths", "min_filter", "max_filter", "erode", "dilate", "opening", "closing",
]

FOOTPRINTS = ("disk", "square")
ALGORITHMS = ("table", "vhgw")
_DIRECT_MAX_K = 2          # 1-D windows up to 5 cells: plain shifted comparisons


def disk(radius_px: int) -> np.ndarray:
    """Boolean disk footprint `(2r+1, 2r+1)`, equal to `skimage.morphology.disk(radius_px)`."""
    r = _check_radius(radius_px)
    d = np.arange(-r, r + 1)
    return d[:, None] ** 2 + d[None, :] ** 2 <= r * r


def chord_half_widths(radius_px: int) -> list[int]:
    """Half-width `c(dy) = floor(sqrt(r^2 - dy^2))` of the disk's row at offset dy = -r..r."""
    r = _check_radius(radius_px)
    return [math.isqrt(r * r - dy * dy) for dy in range(-r, r + 1)]


def _check_radius(radius_px, name: str = "radius_px") -> int:
    if isinstance(radius_px, bool) or not isinstance(radius_px, (int, np.integer)) or radius_px < 0:
        raise ValueError(f"{name} must be an int >= 0, got {radius_px!r}")
    return int(radius_px)


def _identity(dtype, op) -> Array:
    """Identity of `op` for `dtype`: +inf/-inf for floats, the int range ends otherwise."""
    if jnp.issubdtype(dtype, jnp.floating):
        value = np.inf if op is jnp.minimum else -np.inf
    elif jnp.issubdtype(dtype, jnp.integer) or dtype == jnp.bool_:
        info = jnp.iinfo(dtype) if dtype != jnp.bool_ else None
        if info is None:
            value = op is jnp.minimum
        else:
            value = info.max if op is jnp.minimum else info.min
    else:
        raise ValueError(f"morphology needs a float, int or bool raster, got {dtype}")
    return jnp.asarray(value, dtype)


def _line(x: Array, k: int, axis: int, op, fill, algorithm: str) -> Array:
    """Running `op` over `[i - k, i + k]` along `axis`, border = `fill`."""
    if k <= _DIRECT_MAX_K:
        return running_direct(x, k, axis, op, fill)
    if algorithm == "vhgw":
        return running_vhgw(x, k, axis, op, fill)
    xp = pad_axis(x, k, k, axis, fill)
    return SparseTable(xp, 2 * k + 1, axis=axis, op=op).window(0, 2 * k + 1, x.shape[axis])


def _square(x: Array, r: int, op, fill, algorithm: str) -> Array:
    return _line(_line(x, r, 1, op, fill, algorithm), r, 0, op, fill, algorithm)


def _disk(x: Array, r: int, op, fill, algorithm: str) -> Array:
    h, w = x.shape
    chords = chord_half_widths(r)
    widths = sorted(set(chords))
    xp = pad_axis(x, r, r, 0, fill)                                 # (h + 2r, w)
    if algorithm == "vhgw":
        rows = {k: _line(xp, k, 1, op, fill, algorithm) for k in widths}
    else:
        xpp = pad_axis(xp, r, r, 1, fill)                           # (h + 2r, w + 2r)
        table = SparseTable(xpp, 2 * r + 1, axis=1, op=op)
        rows = {k: table.window(r - k, 2 * k + 1, w) for k in widths}  # (h + 2r, w) each
    out = None
    for i, k in enumerate(chords):                                  # i = dy + r
        shifted = lax.slice_in_dim(rows[k], i, i + h, axis=0)
        out = shifted if out is None else op(out, shifted)
    return out


def _disk_traced(x: Array, r: Int[Array, ""], max_r: int, op, fill) -> Array:
    """`_disk` for a traced radius `0 <= r <= max_r` (clipped into that range)."""
    h, w = x.shape
    r = jnp.clip(jnp.asarray(r, jnp.int32), 0, max_r)
    xpp = pad_axis(pad_axis(x, max_r, max_r, 0, fill), max_r, max_r, 1, fill)    # (h + 2R, w + 2R)
    width = xpp.shape[1]
    levels = SparseTable(xpp, 2 * max_r + 1, axis=1, op=op).levels
    table = jnp.stack([pad_axis(m, 0, width - m.shape[1], 1, fill) for m in levels])
    chords = np.zeros((max_r + 1, 2 * max_r + 1), np.int32)   # [r, dy + R]: half-width of row dy
    for radius in range(1, max_r + 1):
        chords[radius, max_r - radius:max_r + radius + 1] = chord_half_widths(radius)
    level_of = np.array([(2 * k + 1).bit_length() - 1 for k in range(max_r + 1)], np.int32)
    chords, level_of = jnp.asarray(chords), jnp.asarray(level_of)

    def row(i, out):                                        # i = dy + r
        dy = i - r
        k = chords[r, dy + max_r]
        level = level_of[k]
        start = max_r - k                                   # the chord [x - k, x + k], padded coordinates
        tail = start + 2 * k + 1 - jnp.left_shift(1, level)
        head_rows = lax.dynamic_slice(table, (level, max_r + dy, start), (1, h, w))[0]
        tail_rows = lax.dynamic_slice(table, (level, max_r + dy, tail), (1, h, w))[0]
        return op(out, op(head_rows, tail_rows))

    return lax.fori_loop(0, 2 * r + 1, row, jnp.full((h, w), fill, x.dtype))


def _reduce(z: Grey, valid: Mask | None, radius_px: Radius, footprint: str, op, algorithm: str,
            max_radius_px: int | None) -> Grey:
    if max_radius_px is None:
        r = _check_radius(radius_px)
    else:
        max_radius_px = _check_radius(max_radius_px, "max_radius_px")
        if footprint != "disk":
            raise ValueError(f"a traced radius (max_radius_px) needs the disk footprint, got {footprint!r}")
        if isinstance(radius_px, (int, np.integer)) and not 0 <= radius_px <= max_radius_px:
            raise ValueError(f"radius_px must lie in 0..max_radius_px={max_radius_px}, got {radius_px!r}")
    if footprint not in FOOTPRINTS:
        raise ValueError(f"footprint must be one of {FOOTPRINTS}, got {footprint!r}")
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {ALGORITHMS}, got {algorithm!r}")
    z = jnp.asarray(z)
    if z.ndim != 2:
        raise ValueError(f"expected a raster (h, w), got shape {z.shape}")
    fill = _identity(z.dtype, op)
    if valid is not None:
        if valid.shape != z.shape:
            raise ValueError(f"valid shape {valid.shape} != raster shape {z.shape}")
        z = jnp.where(valid, z, fill)
    if max_radius_px is not None:
        return _disk_traced(z, radius_px, max_radius_px, op, fill)
    if r == 0:
        return z
    if footprint == "square":
        return _square(z, r, op, fill, algorithm)
    return _disk(z, r, op, fill, algorithm)


def min_filter(
    z: Grey, valid: Mask | None = None, *, radius_px: Radius, footprint: str = "disk", algorithm: str = "table",
    max_radius_px: int | None = None,
) -> Grey:
    """Grey erosion: the minimum of the valid cells under the footprint centred on each cell.

    Args:
      z: raster `(h, w)` (float, int or bool), e.g. elevations [m].
      valid: cells to use, bool `(h, w)`; None = all. Others count as `+inf`.
      radius_px: footprint radius in cells (static; each value compiles once).
      footprint: `"disk"` or `"square"` (static).
      algorithm: `"table"` (doubling table, default) or `"vhgw"` (van Herk / Gil-Werman) for the
        1-D running min/max (static); results are identical.
      max_radius_px: None (`radius_px` static), or the largest radius a traced `radius_px` may
        take (static; disk only): one program for every radius up to it, e.g. inside a loop
        over radii. A traced radius outside `0..max_radius_px` is clipped into it; `algorithm`
        does not apply. Its loop over the disk's rows has a traced length, so reverse-mode
        derivatives (`jax.grad`) need the static form (`jvp` works with both).

    Returns:
      `(h, w)`, dtype of `z`; `+inf` (dtype max) where the window holds no valid cell.
      Equals `scipy.ndimage.grey_erosion(where(valid, z, inf), footprint=F, mode="constant",
      cval=inf)` exactly.
    """
    return _reduce(z, valid, radius_px, footprint, jnp.minimum, algorithm, max_radius_px)


def max_filter(
    z: Grey, valid: Mask | None = None, *, radius_px: Radius, footprint: str = "disk", algorithm: str = "table",
    max_radius_px: int | None = None,
) -> Grey:
    """Grey dilation: the maximum of the valid cells under the footprint (see `min_filter`).

    Returns `-inf` (dtype min) where the window holds no valid cell. Equals
    `scipy.ndimage.grey_dilation(where(valid, z, -inf), footprint=F, mode="constant", cval=-inf)`.
    """
    return _reduce(z, valid, radius_px, footprint, jnp.maximum, algorithm, max_radius_px)


erode = min_filter
dilate = max_filter


def opening(
    z: Grey, valid: Mask | None = None, *, radius_px: Radius, footprint: str = "disk", algorithm: str = "table",
    max_radius_px: int | None = None,
) -> Grey:
    """Grey opening: erosion then dilation, both over valid cells only.

    Args/units as `min_filter`. Returns `(h, w)`: `<= z` on valid cells (anti-extensive),
    `-inf` where no valid cell is within the footprint's reach. This is the opening of
    SMRF's progressive filter (Pingel et al. 2013, Sec. 2.2) and PMF (Zhang et al. 2003, Eq. 1).
    """
    kwargs = dict(radius_px=radius_px, footprint=footprint, algorithm=algorithm, max_radius_px=max_radius_px)
    return max_filter(min_filter(z, valid, **kwargs), valid, **kwargs)


def closing(
    z: Grey, valid: Mask | None = None, *, radius_px: Radius, footprint: str = "disk", algorithm: str = "table",
    max_radius_px: int | None = None,
) -> Grey:
    """Grey closing: dilation then erosion over valid cells; `>= z` on valid cells (extensive)
    and idempotent. Args/units as `min_filter`."""
    kwargs = dict(radius_px=radius_px, footprint=footprint, algorithm=algorithm, max_radius_px=max_radius_px)
    return min_filter(max_filter(z, valid, **kwargs), valid, **kwargs)

