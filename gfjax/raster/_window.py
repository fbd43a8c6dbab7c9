"""1-D sliding-window min/max along one raster axis: the building blocks of `morphology.py`.

Two exact O(1)-amortised forms (max and min only select values, so both are bit-exact):

* `running_vhgw`: van Herk (1992) / Gil & Werman (1993). Cut the padded line into blocks of
  the window width `W = 2k + 1`; a block-wise prefix max `g` and suffix max `h` give
  `max(x[i-k .. i+k]) = max(h[i-k], g[i+k])`: 3 comparisons per cell for any `k`. The block
  scans are unrolled over the W positions of a block (W slices, one fused loop):
  `lax.cummax` lowers to a `reduce_window` over the whole block on CPU (O(W) per cell) and
  `lax.associative_scan` over a short minor axis to many small strided ops; on 1000 x 1000,
  W = 37, those measured ~50 ms and ~28 ms per pass against ~2-4 ms unrolled.
* `SparseTable`: doubling levels `M_j[i] = max(x[i .. i + 2^j - 1])` (log2 W passes) answer any
  window width `W` with one comparison, `max(M_m[i], M_m[i + W - 2^m])`, `2^m <= W < 2^{m+1}`.
  A disk needs one window per distinct chord width; the levels are shared by all of them.

All functions take the reduction `op` (`jnp.maximum` or `jnp.minimum`) and its identity
`fill`, which also pads the borders (scipy `mode="constant", cval=fill`).
"""
from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
from jax import lax
from jaxtyping import Array

Op = Callable[[Array, Array], Array]

__all__ = ["running_vhgw", "running_direct", "pad_axis", "SparseTable"]


def pad_axis(x: Array, before: int, after: int, axis: int, fill) -> Array:
    """Pad `x` along `axis` with the constant `fill`."""
    widths = [(0, 0)] * x.ndim
    widths[axis] = (before, after)
    return jnp.pad(x, widths, constant_values=jnp.asarray(fill, x.dtype))


def running_direct(x: Array, k: int, axis: int, op: Op, fill) -> Array:
    """`op` over the window `[i - k, i + k]` along `axis` by 2k shifted comparisons (small k)."""
    n = x.shape[axis]
    xp = pad_axis(x, k, k, axis, fill)
    out = lax.slice_in_dim(xp, 0, n, axis=axis)
    for s in range(1, 2 * k + 1):
        out = op(out, lax.slice_in_dim(xp, s, s + n, axis=axis))
    return out


def _block_scan(blocks: Array, axis: int, op: Op, reverse: bool) -> Array:
    """Inclusive prefix (or suffix) `op` along the short `axis` of `blocks`, unrolled."""
    width = blocks.shape[axis]
    order = range(width - 1, -1, -1) if reverse else range(width)
    scanned, acc = [None] * width, None
    for j in order:
        piece = lax.index_in_dim(blocks, j, axis=axis, keepdims=True)
        acc = piece if acc is None else op(acc, piece)
        scanned[j] = acc
    return jnp.concatenate(scanned, axis=axis)


def running_vhgw(x: Array, k: int, axis: int, op: Op, fill) -> Array:
    """`op` over the window `[i - k, i + k]` along `axis` (van Herk / Gil-Werman).

    Args:
      x: array of rank 2. Cells outside the array count as `fill`.
      k: half-width in cells (static), window `2k + 1`.
      axis: 0 (along columns, i.e. vertical) or 1 (along rows, horizontal).
      op: `jnp.maximum` or `jnp.minimum`; `fill` its identity.
    """
    if k == 0:
        return x
    n = x.shape[axis]
    width = 2 * k + 1
    blocks = -(-(n + 2 * k) // width)
    xp = pad_axis(x, k, blocks * width - n - k, axis, fill)
    shape = list(xp.shape)
    shape[axis:axis + 1] = [blocks, width]
    b = xp.reshape(shape)
    prefix = _block_scan(b, axis + 1, op, reverse=False).reshape(xp.shape)
    suffix = _block_scan(b, axis + 1, op, reverse=True).reshape(xp.shape)
    return op(lax.slice_in_dim(suffix, 0, n, axis=axis), lax.slice_in_dim(prefix, 2 * k, 2 * k + n, axis=axis))


class SparseTable:
    """Doubling levels of a padded line, answering window reductions of any width <= `max_width`.

    `SparseTable(xp, max_width, axis, op)` builds `M_0 = xp`, `M_{j+1}[i] = op(M_j[i], M_j[i + 2^j])`
    along `axis` while `2^{j+1} <= max_width`; `window(start, width, length)` returns
    `op(xp[start + i .. start + i + width - 1])` for `i < length` (in padded coordinates).
    """

    def __init__(self, xp: Array, max_width: int, axis: int, op: Op):
        self.axis, self.op = axis, op
        self.levels = [xp]
        step = 1
        while 2 * step <= max_width:
            prev = self.levels[-1]
            m = prev.shape[axis]
            self.levels.append(op(lax.slice_in_dim(prev, 0, m - step, axis=axis),
                                  lax.slice_in_dim(prev, step, m, axis=axis)))
            step *= 2

    def window(self, start: int, width: int, length: int) -> Array:
        level = width.bit_length() - 1
        span = 1 << level
        table = self.levels[level]
        head = lax.slice_in_dim(table, start, start + length, axis=self.axis)
        if span == width:
            return head
        tail_start = start + width - span
        return self.op(head, lax.slice_in_dim(table, tail_start, tail_start + length, axis=self.axis))
