"""Voxel coordinates packed into sortable keys, and exact lookup by binary search.

A voxel `(b, i, j, k)` (batch, then three integer grid indices) is packed into two uint32
words compared lexicographically:

    hi = b << 16 | (i + 2**15)          lo = (j + 2**15) << 16 | (k + 2**15)

so `(hi, lo)` order is the lexicographic order of `(b, i, j, k)`, and translating every
coordinate by the same offset keeps the order (what makes a kernel offset a sorted query).
Packable range: `0 <= b < 2**15` and `-2**15 <= i, j, k < 2**15` (16 km at 0.5 m voxels).
Padding rows get the key `(2**32 - 1, 2**32 - 1)`, which sorts last and equals no valid key
(valid `hi < 2**31`).

No Python dict and no hash table: a set of voxels is its sorted keys, and a lookup is a
vectorised binary search over them (`lookup`), so everything runs under `jit` and `vmap`.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, ArrayLike, Bool, Int, UInt32

COORD_MIN = -(2 ** 15)           # smallest packable grid index i, j, k
COORD_MAX = 2 ** 15 - 1          # largest packable grid index i, j, k
BATCH_MAX = 2 ** 15 - 1          # largest packable batch index b
_BIAS = 2 ** 15
_PAD = np.uint32(0xFFFFFFFF)


def range_message(what: str) -> str:
    return (f"{what}: voxel coordinates must lie in [{COORD_MIN}, {COORD_MAX}] and batch indices in "
            f"[0, {BATCH_MAX}]; rescale, re-origin or tile the points first")


def check_range(coords: Int[ArrayLike, "n 4"], valid: Bool[ArrayLike, " n"], what: str) -> Int[ArrayLike, "n 4"]:
    """`coords`, after checking that every valid row is packable.

    Concrete arrays raise `ValueError` naming the range; traced arrays (inside `jit`) carry
    the same check as `eqx.error_if`, because an unpackable coordinate would otherwise alias
    another voxel silently. Numpy arrays are checked in numpy (a pack made on the host: JAX
    ops would trace and load six small programs per pack shape).
    """
    xp = np if isinstance(coords, np.ndarray) and isinstance(valid, np.ndarray) else jnp
    lo = xp.asarray([0, COORD_MIN, COORD_MIN, COORD_MIN], dtype=xp.int32)
    hi = xp.asarray([BATCH_MAX, COORD_MAX, COORD_MAX, COORD_MAX], dtype=xp.int32)
    bad = xp.any(valid[:, None] & ((coords < lo[None, :]) | (coords > hi[None, :])))
    if isinstance(bad, jax.core.Tracer):
        return eqx.error_if(coords, bad, range_message(what))
    if bool(bad):
        raise ValueError(range_message(what))
    return coords


class Keys(NamedTuple):
    """Packed keys `(n,)` uint32 each."""

    hi: UInt32[Array, " n"]
    lo: UInt32[Array, " n"]


def pack(coords: Int[Array, "n 4"], valid: Bool[Array, " n"]) -> Keys:
    """Keys of `(b, i, j, k)` rows; invalid rows and rows outside the packable range get
    the padding key (a query off the grid then finds nothing)."""
    c = coords.astype(jnp.int32)
    inside = (valid & (c[:, 0] >= 0) & (c[:, 0] <= BATCH_MAX)
              & jnp.all((c[:, 1:] >= COORD_MIN) & (c[:, 1:] <= COORD_MAX), axis=1))
    u = (c + jnp.asarray([[0, _BIAS, _BIAS, _BIAS]], dtype=jnp.int32)).astype(jnp.uint32)
    hi = (u[:, 0] << 16) | u[:, 1]
    lo = (u[:, 2] << 16) | u[:, 3]
    pad = jnp.asarray(_PAD, dtype=jnp.uint32)
    return Keys(jnp.where(inside, hi, pad), jnp.where(inside, lo, pad))


def unpack(keys: Keys) -> Int[Array, "n 4"]:
    """Inverse of `pack` for valid keys, `(n, 4)` int32."""
    mask = jnp.asarray(0xFFFF, dtype=jnp.uint32)
    parts = [keys.hi >> 16, keys.hi & mask, keys.lo >> 16, keys.lo & mask]
    c = jnp.stack([p.astype(jnp.int32) for p in parts], axis=1)
    return c - jnp.asarray([[0, _BIAS, _BIAS, _BIAS]], dtype=jnp.int32)


def is_pad(keys: Keys) -> Bool[Array, " n"]:
    return (keys.hi == _PAD) & (keys.lo == _PAD)


class SortedKeys(NamedTuple):
    """A voxel set ready for lookups: keys in increasing order and `perm`, the row each came
    from (`sorted[s] = keys[perm[s]]`). Padding keys sit at the end."""

    hi: UInt32[Array, " n"]
    lo: UInt32[Array, " n"]
    perm: Int[Array, " n"]


def sort_keys(keys: Keys) -> SortedKeys:
    iota = jnp.arange(keys.hi.shape[0], dtype=jnp.int32)
    hi, lo, perm = lax.sort((keys.hi, keys.lo, iota), num_keys=2, is_stable=True)
    return SortedKeys(hi, lo, perm)


def _less(a_hi, a_lo, b_hi, b_lo):
    return (a_hi < b_hi) | ((a_hi == b_hi) & (a_lo < b_lo))


def lower_bound(table: SortedKeys, query: Keys) -> Int[Array, ...]:
    """Position in `table` of the first key not below each query, `(...)` int32 in `[0, n]`.

    A vectorised binary search: `ceil(log2(n + 1))` steps of two gathers each.
    """
    n = table.hi.shape[0]
    lo = jnp.zeros(query.hi.shape, dtype=jnp.int32)
    if n == 0:
        return lo
    hi = jnp.full(query.hi.shape, n, dtype=jnp.int32)

    def step(_, bounds):
        lo, hi = bounds
        mid = (lo + hi) // 2
        at = jnp.minimum(mid, n - 1)
        before = _less(table.hi[at], table.lo[at], query.hi, query.lo)
        active = lo < hi
        return jnp.where(active & before, mid + 1, lo), jnp.where(active & ~before, mid, hi)

    lo, _ = lax.fori_loop(0, max(1, math.ceil(math.log2(n + 1))), step, (lo, hi))
    return lo


def lookup(table: SortedKeys, query: Keys, *, missing: int) -> Int[Array, ...]:
    """Row of `table` holding each query key, or `missing` where none does.

    Args:
      table: the voxel set (`sort_keys`), `n` rows.
      query: keys of any shape `(...)`; padding keys never match.
      missing: the value returned for a key not in the set (static).
    """
    n = table.hi.shape[0]
    if n == 0:
        return jnp.full(query.hi.shape, missing, dtype=jnp.int32)
    lo = lower_bound(table, query)
    at = jnp.minimum(lo, n - 1)
    found = (lo < n) & (table.hi[at] == query.hi) & (table.lo[at] == query.lo) & ~is_pad(query)
    return jnp.where(found, table.perm[at], missing).astype(jnp.int32)


class UniqueKeys(NamedTuple):
    """The distinct valid keys of a set, sorted, padded to a static capacity.

    Attributes:
      keys: `(capacity,)` keys; rows `>= count` hold the padding key.
      count: int32 scalar, the number of distinct valid keys (may exceed `capacity`).
      overflowed: bool scalar, `count > capacity` (rows were dropped; reallocate).
    """

    keys: Keys
    count: Int[Array, ""]
    overflowed: Bool[Array, ""]


def unique(keys: Keys, *, capacity: int) -> UniqueKeys:
    """Distinct valid keys in increasing order, at most `capacity` of them (static)."""
    s = sort_keys(keys)
    first = ~is_pad(Keys(s.hi, s.lo))
    first = first.at[1:].set(first[1:] & ((s.hi[1:] != s.hi[:-1]) | (s.lo[1:] != s.lo[:-1])))
    rank = jnp.cumsum(first, dtype=jnp.int32) - 1
    count = jnp.sum(first, dtype=jnp.int32)
    dest = jnp.where(first, rank, capacity)                       # out of range -> dropped
    pad = jnp.full((capacity,), _PAD, dtype=jnp.uint32)
    hi = pad.at[dest].set(s.hi, mode="drop")
    lo = pad.at[dest].set(s.lo, mode="drop")
    return UniqueKeys(Keys(hi, lo), count, count > capacity)
