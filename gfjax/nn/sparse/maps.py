"""Kernel maps: which input voxel feeds which output voxel through which kernel offset.

A sparse convolution (Choy et al. 2019, MinkowskiEngine) is

    out[o] = sum over pairs (i, o, d) of  in[i] @ W[d]

where a pair says that input row `i` sits at kernel offset `d` from output row `o`:
`coord_in(i) = stride * coord_out(o) + offset(d)`. One function finds the pairs for every
kind of convolution the U-Net needs:

- submanifold (stride 1, odd kernel, outputs at the input sites): offsets `-r..r` per axis;
- strided (kernel 2, stride 2, outputs at `floor(coord / 2)`): offsets `{0, 1}` per axis;
- transposed (kernel 2, stride 2, back to the finer sites): the strided map with inputs and
  outputs swapped (`KernelMap.transpose`), so the same pairs serve both directions.

Pairs are found by binary searches of the packed input keys (`keys.lower_bound`; jit-able,
no dict): one search per (output row, kernel column), since a column's voxels are consecutive
in key order, so a kernel of edge `k` costs `k**2` searches per row, not `k**3`. They are then
compacted into a list grouped by offset: each
offset's pairs fill whole blocks of `block` rows (the last block of an offset padded with a
sentinel pair), so the convolution is one gather, one batched matmul of `(block, c) @ (c, c')`
per block and one scatter-add, and only neighbours that exist cost multiply-adds. The pair
capacity `n_blocks * block` is static; `plan_blocks` sizes it from the data outside `jit`,
and a map that did not fit says so in `overflowed` (the jax-md pattern).

A map can also stay a `NeighbourTable`: the `(n_out, k)` table itself, a slot per (row,
offset) whether a neighbour is there or not. `conv.table_conv` reads it with no compaction, at
the price of multiply-adds for the missing neighbours: the cheaper form where the input has
few channels and the kernel many offsets, as in a U-Net's stem (kernel 5, 125 offsets).

A U-Net uses each map many times (two residual blocks of two convolutions per level), so
`gfjax.nn.sparse.pyramid` builds every map once per forward pass and hands them to the layers.
"""
from __future__ import annotations

import functools
import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Int

from gfjax.nn.sparse import keys as K

MIN_BLOCK = 16        # smallest block of pairs [rows]
MAX_BLOCK = 4096      # largest block of pairs [rows]


def kernel_offsets(kernel_size: int, *, centred: bool = True) -> np.ndarray:
    """Kernel offsets `(kernel_size**3, 3)` int32 in lexicographic (i, j, k) order.

    Centred kernels (odd sizes, submanifold) span `-r..r`; uncentred ones (strided) span
    `0..kernel_size-1`, so offset `d` of a kernel-2 stride-2 map is the child's position
    `coord % 2` in its parent voxel.
    """
    if kernel_size < 1:
        raise ValueError(f"kernel_size must be >= 1, got {kernel_size}")
    if centred and kernel_size % 2 == 0:
        raise ValueError(f"a centred kernel needs an odd size, got {kernel_size}")
    start = -(kernel_size // 2) if centred else 0
    axis = range(start, start + kernel_size)
    return np.asarray(list(itertools.product(axis, axis, axis)), dtype=np.int32)


class KernelMap(eqx.Module):
    """The pairs of one convolution, grouped by kernel offset in blocks.

    Attributes:
      in_idx: `(n_blocks * block,)` int32 input row of each pair; `n_in` for padding pairs.
      out_idx: `(n_blocks * block,)` int32 output row of each pair; `n_out` for padding pairs.
      block_offset: `(n_blocks,)` int32, the kernel offset of every pair of the block.
      n_pairs: int32 scalar, the pairs found (padding excluded).
      overflowed: bool scalar, some pairs did not fit in `n_blocks` blocks (they were
        dropped: the caller must rebuild with more blocks).
      in_coords, in_valid, out_coords, out_valid: the two voxel sets, `(n_in, 4)`,
        `(n_in,)`, `(n_out, 4)`, `(n_out,)`: what a layer needs to build its output tensor.
      kernel_volume, block: static sizes.
    """

    in_idx: Int[Array, " p"]
    out_idx: Int[Array, " p"]
    block_offset: Int[Array, " nb"]
    n_pairs: Int[Array, ""]
    overflowed: Bool[Array, ""]
    in_coords: Int[Array, "n_in 4"]
    in_valid: Bool[Array, " n_in"]
    out_coords: Int[Array, "n_out 4"]
    out_valid: Bool[Array, " n_out"]
    kernel_volume: int = eqx.field(static=True)
    block: int = eqx.field(static=True)

    @property
    def n_in(self) -> int:
        return self.in_coords.shape[0]

    @property
    def n_out(self) -> int:
        return self.out_coords.shape[0]

    @property
    def n_blocks(self) -> int:
        return self.block_offset.shape[0]

    def transpose(self) -> KernelMap:
        """The same pairs read the other way: the map of the transposed convolution.

        `out'[i] = sum_(i, o, d) in'[o] @ W[d]`: a kernel-2 stride-2 map transposed takes
        each coarse voxel back to its children, weight `d` for the child at offset `d`.
        """
        return KernelMap(self.out_idx, self.in_idx, self.block_offset, self.n_pairs, self.overflowed,
                         self.out_coords, self.out_valid, self.in_coords, self.in_valid,
                         self.kernel_volume, self.block)


class NeighbourTable(eqx.Module):
    """Every (output row, kernel offset) slot of a convolution, present or not: the other form
    of a map, for `table_conv`.

    Attributes:
      table: `(n_out, k)` int32, the input row at each offset, `n_in` where there is none
        (`neighbour_table`).
      in_coords, in_valid, out_coords, out_valid: the two voxel sets, as `KernelMap`'s.
    """

    table: Int[Array, "n_out k"]
    in_coords: Int[Array, "n_in 4"]
    in_valid: Bool[Array, " n_in"]
    out_coords: Int[Array, "n_out 4"]
    out_valid: Bool[Array, " n_out"]

    @property
    def kernel_volume(self) -> int:
        return self.table.shape[1]

    @property
    def n_in(self) -> int:
        return self.in_coords.shape[0]

    @property
    def n_out(self) -> int:
        return self.out_coords.shape[0]


TABLE_STEP_ROWS = 4096      # output rows per step of `neighbour_table`


@functools.partial(jax.jit, static_argnames=("kernel_size", "centred", "stride", "step_rows"))
def neighbour_table(in_coords: Int[Array, "n_in 4"], in_valid: Bool[Array, " n_in"],
                    out_coords: Int[Array, "n_out 4"], out_valid: Bool[Array, " n_out"], *,
                    kernel_size: int, centred: bool = True, stride: int = 1,
                    step_rows: int = TABLE_STEP_ROWS) -> Int[Array, "n_out k"]:
    """For every output row and offset, the input row at `stride * out + offset`.

    Offsets are `kernel_offsets(kernel_size, centred=centred)`. Output rows are searched
    `step_rows` at a time (static), and a step with no valid row is skipped, so padding rows
    (most of a coarse level's capacity) cost no search.

    Returns:
      `(n_out, k)` int32, an input row or `n_in` (none there); invalid output rows and
      invalid input rows never take part.
    """
    n_in, n_out = in_coords.shape[0], out_coords.shape[0]
    volume = len(kernel_offsets(kernel_size, centred=centred))
    if n_in == 0:
        return jnp.full((n_out, volume), n_in, jnp.int32)
    table = K.sort_keys(K.pack(in_coords, in_valid))
    start = -(kernel_size // 2) if centred else 0
    axis = np.arange(start, start + kernel_size, dtype=np.int32)
    dx, dy = (jnp.asarray(a.reshape(-1)) for a in np.meshgrid(axis, axis, indexing="ij"))
    columns = kernel_size * kernel_size

    def search(rows):                                       # (r, 4) coords + (r,) valid -> (r, volume)
        coords, valid = rows
        r = coords.shape[0]

        def column_keys(z):                                 # (r * columns,) keys at height z
            c = jnp.stack([jnp.broadcast_to(coords[:, :1], (r, columns)),
                           stride * coords[:, 1:2] + dx[None, :], stride * coords[:, 2:3] + dy[None, :],
                           jnp.broadcast_to(z[:, None], (r, columns))], axis=-1)
            return K.pack(c.reshape(-1, 4), jnp.repeat(valid, columns))

        z0 = stride * coords[:, 3] + start
        first = K.lower_bound(table, column_keys(jnp.clip(z0, K.COORD_MIN, K.COORD_MAX)))
        targets = [column_keys(z0 + dz) for dz in range(kernel_size)]
        found = [jnp.full(first.shape, n_in, jnp.int32) for _ in range(kernel_size)]
        for j in range(kernel_size):
            # the voxels of a column are consecutive in key order, so the one at height z0 + dz
            # is among the kernel_size keys from the first one at or above z0
            at = jnp.minimum(first + j, n_in - 1)
            hi, lo, row = table.hi[at], table.lo[at], table.perm[at]
            inside = first + j < n_in
            for dz, t in enumerate(targets):
                hit = inside & (hi == t.hi) & (lo == t.lo) & ~K.is_pad(t)
                found[dz] = jnp.where(hit, row, found[dz])
        return jnp.stack(found, axis=-1).reshape(r, volume)

    if n_out <= step_rows:
        return search((out_coords, out_valid))
    steps = -(-n_out // step_rows)
    extra = steps * step_rows - n_out
    coords = jnp.concatenate([out_coords, jnp.zeros((extra, 4), out_coords.dtype)]).reshape(steps, -1, 4)
    valid = jnp.concatenate([out_valid, jnp.zeros((extra,), bool)]).reshape(steps, -1)

    def step(rows):
        return lax.cond(jnp.any(rows[1]), search, lambda _: jnp.full((step_rows, volume), n_in, jnp.int32), rows)

    return lax.map(step, (coords, valid)).reshape(-1, volume)[:n_out]


def inner_table(table: Int[Array, "n_out k"], kernel_size: int) -> Int[Array, "n_out k2"]:
    """The neighbour table of a smaller centred kernel (`kernel_size`), read off the table of
    a larger centred one (its offsets are a subset): no search."""
    big = round(table.shape[1] ** (1 / 3))
    if big ** 3 != table.shape[1] or big % 2 == 0 or kernel_size % 2 == 0 or kernel_size > big:
        raise ValueError(f"inner_table: a centred kernel {kernel_size} is not inside a table of {table.shape[1]} offsets")
    offsets = kernel_offsets(big)
    inside = np.flatnonzero(np.all(np.abs(offsets) <= kernel_size // 2, axis=1))
    return table[:, inside]


def pairs_per_offset(table: Int[Array, "n_out k"], n_in: int) -> Int[Array, " k"]:
    """Number of pairs of each offset, `(k,)` int32."""
    return jnp.sum(table < n_in, axis=0, dtype=jnp.int32)


def plan_blocks(counts: np.ndarray | Array, *, block: int | None = None) -> tuple[int, int]:
    """Static `(block, n_blocks)` that hold pairs with these per-offset counts (host).

    The block is the largest power of two in `[MIN_BLOCK, MAX_BLOCK]` that keeps the padding
    (at most one partial block per offset) under an eighth of the pairs; `n_blocks` is then
    rounded up to `2**j` or `1.5 * 2**j` so that similar inputs share one compiled shape.
    """
    counts = np.asarray(counts, dtype=np.int64)
    total, k = int(counts.sum()), max(1, len(counts))
    if block is None:
        block = MIN_BLOCK
        while block * 2 <= MAX_BLOCK and k * block * 2 * 8 <= total:
            block *= 2
    needed = int(np.sum(-(-counts // block)))
    return block, bucket(max(needed, 1))


def bucket(n: int) -> int:
    if n <= 2:
        return n
    j = math.ceil(math.log2(n)) - 1
    return 3 * 2 ** (j - 1) if 3 * 2 ** (j - 1) >= n else 2 ** (j + 1)


@functools.partial(jax.jit, static_argnames=("n_in", "block", "n_blocks"))
def pairs_from_table(table: Int[Array, "n_out k"], *, n_in: int, block: int, n_blocks: int,
                     in_coords, in_valid, out_coords, out_valid) -> KernelMap:
    """Compact a neighbour table into pairs grouped by offset, `block` rows per block."""
    n_out, k = table.shape
    present = table < n_in                                                  # (n_out, k)
    counts = jnp.sum(present, axis=0, dtype=jnp.int32)                      # (k,)
    blocks_of = (counts + block - 1) // block
    first_block = jnp.cumsum(blocks_of) - blocks_of                         # (k,)
    used_blocks = jnp.sum(blocks_of)
    rank = jnp.cumsum(present, axis=0, dtype=jnp.int32) - 1                 # (n_out, k)
    slot = first_block[None, :] * block + rank
    capacity = n_blocks * block
    slot = jnp.where(present & (slot < capacity), slot, capacity)           # dropped -> out of range
    rows = jnp.broadcast_to(jnp.arange(n_out, dtype=jnp.int32)[:, None], table.shape)
    in_idx = jnp.full((capacity,), n_in, jnp.int32).at[slot.reshape(-1)].set(table.reshape(-1), mode="drop")
    out_idx = jnp.full((capacity,), n_out, jnp.int32).at[slot.reshape(-1)].set(rows.reshape(-1), mode="drop")
    # block b belongs to the last offset whose first block is <= b (empty offsets share starts)
    block_offset = jnp.searchsorted(first_block, jnp.arange(n_blocks, dtype=first_block.dtype), side="right") - 1
    block_offset = jnp.clip(block_offset, 0, k - 1).astype(jnp.int32)
    return KernelMap(in_idx, out_idx, block_offset, jnp.sum(counts), used_blocks > n_blocks,
                     in_coords, in_valid, out_coords, out_valid, k, block)


def _resolve_blocks(table, n_in, block, n_blocks):
    if n_blocks is not None:
        if block is None:
            raise ValueError("n_blocks needs block as well (both static)")
        return block, n_blocks
    if isinstance(table, jax.core.Tracer):
        # no data to plan from: room for every (row, offset), the worst case
        block = block or MIN_BLOCK
        return block, table.shape[1] * (-(-table.shape[0] // block))
    return plan_blocks(np.asarray(pairs_per_offset(table, n_in)), block=block)


def submanifold_map(coords: Int[ArrayLike, "n 4"], valid: Bool[ArrayLike, " n"], *, kernel_size: int = 3,
                    block: int | None = None, n_blocks: int | None = None) -> KernelMap:
    """Map of a submanifold convolution: outputs exactly at the input's voxels.

    Args:
      coords: `(n, 4)` int32 `(b, i, j, k)` voxel coordinates, any row order.
      valid: `(n,)` bool; padding rows neither give nor take features.
      kernel_size: odd edge of the cubic kernel (static).
      block, n_blocks: static pair capacity (`plan_blocks`). When omitted, concrete inputs
        are planned from their own counts; traced inputs get room for every (row, offset).
    """
    coords = K.check_range(jnp.asarray(coords, jnp.int32), jnp.asarray(valid, bool), "submanifold_map")
    valid = jnp.asarray(valid, bool)
    table = neighbour_table(coords, valid, coords, valid, kernel_size=kernel_size)
    block, n_blocks = _resolve_blocks(table, coords.shape[0], block, n_blocks)
    return pairs_from_table(table, n_in=coords.shape[0], block=block, n_blocks=n_blocks,
                            in_coords=coords, in_valid=valid, out_coords=coords, out_valid=valid)


@functools.partial(jax.jit, static_argnames=("capacity", "stride"))
def downsample(coords: Int[Array, "n 4"], valid: Bool[Array, " n"], *, capacity: int,
               stride: int = 2) -> tuple[Int[Array, "m 4"], Bool[Array, " m"], Bool[Array, ""]]:
    """The coarser voxel set `floor(coord / stride)` (batch kept), sorted, padded.

    Returns:
      `(coords (capacity, 4) int32, valid (capacity,), overflowed)`; padding rows have
      coordinates 0. `overflowed` means more than `capacity` coarse voxels exist.
    """
    coords = jnp.asarray(coords, jnp.int32)
    coarse = jnp.concatenate([coords[:, :1], jnp.floor_divide(coords[:, 1:], stride)], axis=1)
    u = K.unique(K.pack(coarse, valid), capacity=capacity)
    out_valid = jnp.arange(capacity) < u.count
    out = jnp.where(out_valid[:, None], K.unpack(u.keys), 0)
    return out, out_valid, u.overflowed


def strided_map(fine_coords, fine_valid, coarse_coords, coarse_valid, *, kernel_size: int = 2,
                stride: int = 2, block: int | None = None, n_blocks: int | None = None) -> KernelMap:
    """Map of a strided convolution from the fine set to the coarse set (`downsample`).

    Output row `o` gathers the input voxels at `stride * coarse(o) + offset`, offsets
    `0..kernel_size-1` per axis. `.transpose()` gives the transposed convolution's map.
    """
    fine_coords, coarse_coords = jnp.asarray(fine_coords, jnp.int32), jnp.asarray(coarse_coords, jnp.int32)
    fine_valid, coarse_valid = jnp.asarray(fine_valid, bool), jnp.asarray(coarse_valid, bool)
    table = neighbour_table(fine_coords, fine_valid, coarse_coords, coarse_valid,
                            kernel_size=kernel_size, centred=False, stride=stride)
    block, n_blocks = _resolve_blocks(table, fine_coords.shape[0], block, n_blocks)
    return pairs_from_table(table, n_in=fine_coords.shape[0], block=block, n_blocks=n_blocks,
                            in_coords=fine_coords, in_valid=fine_valid,
                            out_coords=coarse_coords, out_valid=coarse_valid)
