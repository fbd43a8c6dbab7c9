"""Sparse convolution as gather -> matmul -> scatter-add over a kernel map.

    out[o] = sum over the map's pairs (i, o, d) of feats[i] @ weight[d]

Only pairs whose input voxel exists are computed: the map (`gfjax.nn.sparse.maps`) lists
them grouped by kernel offset in blocks of `block` rows, so one block is a dense
`(block, c_in) @ (c_in, c_out)` product with a single weight. Padding pairs point at a zero
row appended to the input and at a discarded row appended to the output.

A map's pair capacity is static and sized for the densest data it must hold, so most of
its blocks are often padding (a pack of SparseGF patches fills a fifth to a third of its
level-0 map, and a fiftieth of its coarsest). Two schedules, exact to each other (the same
products added in the same order):

- `chunk_blocks=m` (default: about `STEP_PAIRS` pairs a step): a `lax.scan` over groups of
  `m` blocks, adding into the output as it goes; a step whose blocks hold no pair is skipped
  (`lax.cond`, in the gradient too), so the cost follows the pairs found, not the capacity,
  and the working memory is `m * block` pairs whatever the map's size;
- `chunk_blocks=0`: every block at once (one gather, one batched matmul, one scatter-add),
  padding included.

`table_conv` is the same sum read off a `NeighbourTable`: each output row gathers its `k`
neighbours (a zero row where one is missing) into one `(rows, k * c) @ (k * c, d)` product, in
chunks of rows (a chunk with no neighbour at all, padding, is skipped). No compaction and no scatter: the cheaper form for few input channels and
many offsets (a U-Net's stem), although missing neighbours cost multiply-adds too.

The gradient is JAX's own: the gather transposes to a scatter-add into the input, the matmul
to its two transposes. On CPU the scatter-adds are deterministic; on a GPU XLA's float
scatter-add may not be.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, ArrayLike, Float

from gfjax.nn.sparse.maps import KernelMap, NeighbourTable

STEP_PAIRS = 8192          # pairs per step of `sparse_conv`'s default schedule


def sparse_conv(feats: Float[ArrayLike, "n_in c"], weight: Float[ArrayLike, "k c d"], kmap: KernelMap, *,
                chunk_blocks: int | None = None) -> Float[Array, "n_out d"]:
    """Apply a sparse convolution.

    Args:
      feats: `(n_in, c)` input features; rows absent from the map (padding) are never read.
      weight: `(k, c, d)`, one matrix per kernel offset, `k = kmap.kernel_volume`.
      kmap: the pairs (`submanifold_map`, `strided_map`, or one `.transpose()`d).
      chunk_blocks: blocks per scan step (static); `None`: `STEP_PAIRS // kmap.block` (at
        least 1); 0: all blocks at once.

    Returns:
      `(n_out, d)` features; rows with no pair (padding, isolated outputs of a strided map)
      are 0.
    """
    feats, weight = jnp.asarray(feats), jnp.asarray(weight)
    if feats.shape[0] != kmap.n_in:
        raise ValueError(f"sparse_conv: feats has {feats.shape[0]} rows, the map expects {kmap.n_in}")
    if weight.ndim != 3 or weight.shape[0] != kmap.kernel_volume or weight.shape[1] != feats.shape[1]:
        raise ValueError(f"sparse_conv: weight must have shape ({kmap.kernel_volume}, {feats.shape[1]}, c_out), "
                         f"got {weight.shape}")
    c_out = weight.shape[2]
    x = jnp.concatenate([feats, jnp.zeros((1, feats.shape[1]), feats.dtype)])      # row n_in = 0
    block, n_blocks = kmap.block, kmap.n_blocks
    if chunk_blocks is None:
        chunk_blocks = max(1, STEP_PAIRS // block)
    if chunk_blocks < 0:
        raise ValueError(f"sparse_conv: chunk_blocks must be >= 0, got {chunk_blocks}")
    if chunk_blocks == 0:
        y = _blocks(x, weight, kmap.in_idx, kmap.block_offset, block)
        out = jnp.zeros((kmap.n_out + 1, c_out), y.dtype).at[kmap.out_idx].add(y)
        return out[:-1]
    chunk_blocks = min(chunk_blocks, n_blocks)
    n_steps = -(-n_blocks // chunk_blocks)
    extra = n_steps * chunk_blocks - n_blocks                   # sentinel blocks to even the chunks
    in_idx = jnp.concatenate([kmap.in_idx, jnp.full((extra * block,), kmap.n_in, jnp.int32)])
    out_idx = jnp.concatenate([kmap.out_idx, jnp.full((extra * block,), kmap.n_out, jnp.int32)])
    block_offset = jnp.concatenate([kmap.block_offset, jnp.zeros((extra,), jnp.int32)])

    def step(out, chunk):
        i, o, b = chunk
        return lax.cond(jnp.any(i < kmap.n_in), lambda out: out.at[o].add(_blocks(x, weight, i, b, block)),
                        lambda out: out, out), None

    chunks = (in_idx.reshape(n_steps, -1), out_idx.reshape(n_steps, -1), block_offset.reshape(n_steps, -1))
    dtype = jnp.result_type(feats.dtype, weight.dtype)
    out, _ = lax.scan(step, jnp.zeros((kmap.n_out + 1, c_out), dtype), chunks)
    return out[:-1]


def _blocks(x, weight, in_idx, block_offset, block):
    """Products of the pairs of some blocks, `(n_blocks * block, d)`."""
    g = x[in_idx].reshape(block_offset.shape[0], block, x.shape[1])
    y = jnp.einsum("nbc,ncd->nbd", g, weight[block_offset], preferred_element_type=g.dtype)
    return y.reshape(-1, weight.shape[2])



TABLE_CHUNK_ROWS = 8192      # output rows per step of `table_conv`


def table_conv(feats: Float[ArrayLike, "n_in c"], weight: Float[ArrayLike, "k c d"], table: NeighbourTable, *,
               chunk_rows: int = TABLE_CHUNK_ROWS) -> Float[Array, "n_out d"]:
    """Apply a sparse convolution given as a neighbour table (equal to `sparse_conv` on the
    map of the same pairs, up to the order of the float sums).

    Args:
      feats: `(n_in, c)` input features.
      weight: `(k, c, d)`, one matrix per kernel offset.
      table: the `(n_out, k)` table of input rows (`n_in`: no neighbour).
      chunk_rows: output rows per step (static): bounds the gathered `(rows, k * c)` block;
        each step is rematerialised in the backward pass instead of kept.

    Returns:
      `(n_out, d)`; rows whose every slot is empty (padding) are 0.
    """
    feats, weight = jnp.asarray(feats), jnp.asarray(weight)
    t = table.table
    n_out, k = t.shape
    if feats.shape[0] != table.n_in:
        raise ValueError(f"table_conv: feats has {feats.shape[0]} rows, the table expects {table.n_in}")
    if weight.ndim != 3 or weight.shape[0] != k or weight.shape[1] != feats.shape[1]:
        raise ValueError(f"table_conv: weight must have shape ({k}, {feats.shape[1]}, c_out), got {weight.shape}")
    x = jnp.concatenate([feats, jnp.zeros((1, feats.shape[1]), feats.dtype)])      # row n_in = 0
    w = weight.reshape(k * feats.shape[1], weight.shape[2])

    @jax.checkpoint
    def rows(block):
        return x[block].reshape(block.shape[0], -1) @ w

    if n_out <= chunk_rows:
        return rows(t)

    def step(block):                                     # rows with no neighbour (padding) cost nothing
        return lax.cond(jnp.any(block < table.n_in), rows,
                        lambda b: jnp.zeros((b.shape[0], w.shape[1]), jnp.result_type(x, w)), block)

    steps = -(-n_out // chunk_rows)
    padded = jnp.concatenate([t, jnp.full((steps * chunk_rows - n_out, k), table.n_in, t.dtype)])
    out = lax.map(step, padded.reshape(steps, chunk_rows, k))
    return out.reshape(steps * chunk_rows, -1)[:n_out]
