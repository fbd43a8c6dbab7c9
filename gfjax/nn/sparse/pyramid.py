"""Every kernel map of a sparse U-Net, built once per forward pass.

A U-Net of depth `L` works on the voxel sets `V_0` (the input) and `V_l = floor(V_{l-1} / 2)`
for `l = 1..L`. Each level's residual blocks share one submanifold map (kernel 3), the stem
has its own (kernel 5 on `V_0`, kept as a `NeighbourTable`: few input channels, 125 offsets),
each down block a strided map `V_l -> V_{l+1}`, and each up block that map's transpose. `Pyramid` holds all of them; building it is the only place
coordinates are searched, so a forward pass searches each set once, however many layers use it.

Shapes are static: `plan_pyramid` runs outside `jit`, counts the voxels of every level and
the pairs of every map on the actual data (one jitted pass with room for the worst case),
and rounds them up to a few bucket sizes; `build_pyramid` then builds the maps inside `jit`
with exactly those capacities. Several samples batched with `vmap` share one plan
(`PyramidPlan.union`).
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Int

from gfjax.nn.sparse import keys as K
from gfjax.nn.sparse.maps import (
    KernelMap,
    NeighbourTable,
    bucket,
    downsample,
    inner_table,
    neighbour_table,
    pairs_from_table,
    pairs_per_offset,
    plan_blocks,
)


class PyramidPlan(NamedTuple):
    """Static sizes of a pyramid (hashable: a `jit` static argument).

    Attributes:
      capacities: rows of `V_0 .. V_L` (`V_0`'s is the input's own).
      stem_kernel: kernel size of the stem's submanifold table on `V_0`.
      submanifold: `(block, n_blocks)` of the kernel-3 map of each level `0..L`.
      down: `(block, n_blocks)` of the strided map `V_l -> V_{l+1}`, `l = 0..L-1`.
    """

    capacities: tuple[int, ...]
    stem_kernel: int
    submanifold: tuple[tuple[int, int], ...]
    down: tuple[tuple[int, int], ...]

    @property
    def depth(self) -> int:
        return len(self.capacities) - 1

    def union(self, other: PyramidPlan) -> PyramidPlan:
        """A plan with room for both (element-wise maximum; same depth, stem and blocks)."""
        if (self.depth != other.depth or self.stem_kernel != other.stem_kernel
                or self.capacities[0] != other.capacities[0]):
            raise ValueError("PyramidPlan.union: plans of different depth, stem kernel or input capacity")

        def most(a, b):
            if a[-2] != b[-2]:                              # different blocks: keep the larger block
                return a if a[-2] * a[-1] >= b[-2] * b[-1] else b
            return a[:-1] + (max(a[-1], b[-1]),)
        return PyramidPlan(tuple(max(a, b) for a, b in zip(self.capacities, other.capacities)), self.stem_kernel,
                           tuple(most(a, b) for a, b in zip(self.submanifold, other.submanifold)),
                           tuple(most(a, b) for a, b in zip(self.down, other.down)))


class Pyramid(eqx.Module):
    """The voxel sets and kernel maps of one forward pass.

    Attributes:
      coords, valid: per level `0..L`, `(capacity_l, 4)` int32 and `(capacity_l,)` bool.
      stem: the stem's submanifold table on level 0.
      submanifold: the kernel-3 map of each level.
      down: the strided map from each level to the next (`.transpose()` goes back up).
      overflowed: bool scalar, some level or map did not fit its plan (plan again).
    """

    coords: tuple[Int[Array, "_ 4"], ...]       # each level its own row count
    valid: tuple[Bool[Array, " _"], ...]
    stem: NeighbourTable
    submanifold: tuple[KernelMap, ...]
    down: tuple[KernelMap, ...]
    overflowed: Bool[Array, ""]

    def up(self, level: int) -> KernelMap:
        """Map of the transposed convolution from level `level + 1` back to `level`."""
        return self.down[level].transpose()

    def parent(self, level: int) -> Int[Array, " n"]:
        """Row in level `level + 1` of the voxel holding each voxel of level `level`,
        `(capacity_level,)` int32 (0 on padding rows). Read off the strided map, where every
        voxel is the input of exactly one pair: no search."""
        m = self.down[level]
        parent = jnp.zeros((m.n_in + 1,), jnp.int32).at[m.in_idx].set(m.out_idx)[:-1]
        return jnp.where(m.in_valid, jnp.minimum(parent, m.n_out - 1), 0)


@functools.partial(jax.jit, static_argnames=("depth",))
def _counts(coords, valid, *, depth):
    """Voxels per level and pairs per offset of every map, with room for everything."""
    n = coords.shape[0]
    levels = [(coords, valid)]
    for _ in range(depth):
        c, v, _ = downsample(*levels[-1], capacity=n)
        levels.append((c, v))
    sizes = [jnp.sum(v, dtype=jnp.int32) for _, v in levels]
    sub = [pairs_per_offset(neighbour_table(c, v, c, v, kernel_size=3), n) for c, v in levels]
    down = [pairs_per_offset(neighbour_table(*levels[k], *levels[k + 1], kernel_size=2, centred=False, stride=2), n)
            for k in range(depth)]
    return sizes, sub, down


def plan_pyramid(coords: Int[ArrayLike, "n 4"], valid: Bool[ArrayLike, " n"], *, depth: int,
                 stem_kernel: int = 5, like: PyramidPlan | None = None) -> PyramidPlan:
    """Static sizes for `build_pyramid` from concrete coordinates (outside `jit`).

    With `like` (e.g. `standard_plan`), the block sizes of `like` are kept and `like` itself
    is returned whenever the data fit in it, so that many inputs share one compiled shape;
    only the sizes that do not fit grow.
    """
    coords = K.check_range(jnp.asarray(coords, jnp.int32), jnp.asarray(valid, bool), "plan_pyramid")
    sizes, sub, down = jax.device_get(_counts(coords, jnp.asarray(valid, bool), depth=depth))
    n = coords.shape[0]
    capacities = (n,) + tuple(min(n, bucket(max(int(s), 1))) for s in sizes[1:])
    if like is None:
        return PyramidPlan(capacities, stem_kernel, tuple(plan_blocks(s) for s in sub),
                           tuple(plan_blocks(d) for d in down))
    if like.capacities[0] != n or like.depth != depth or like.stem_kernel != stem_kernel:
        raise ValueError("plan_pyramid: `like` was made for another input size, depth or stem kernel")

    def grow(have, counts):
        block, n_blocks = have[-2], have[-1]
        needed = int(np.sum(-(-np.asarray(counts, np.int64) // block)))
        return have if needed <= n_blocks else have[:-1] + (bucket(needed),)

    return PyramidPlan(tuple(max(a, b) for a, b in zip(like.capacities, capacities)), stem_kernel,
                       tuple(grow(h, c) for h, c in zip(like.submanifold, sub)),
                       tuple(grow(h, c) for h, c in zip(like.down, down)))


def standard_plan(capacity: int, *, depth: int, stem_kernel: int = 5, shrink: float = 1.0,
                  coarse_shrink: float = 2.0, neighbours: float = 8.0,
                  coarse_neighbours: float = 16.0) -> PyramidPlan:
    """A plan that depends on the input capacity only (one compiled shape per capacity).

    Level 1 holds `capacity / shrink` voxels and each further level `coarse_shrink` times
    fewer; the kernel-3 maps of levels 0 and 1 have room for `neighbours` pairs per row of
    their capacity, those of coarser levels `coarse_neighbours`, each strided map one pair per
    finer row and a quarter more (the stem's table has a slot for every offset and needs no
    room).

    The defaults hold every pack of SparseGF patches (0.5 m voxels) measured on the ISPRS
    samples, bcts_2, Topography and autzen: relative to the input capacity, levels 1-4 held
    up to 0.78, 0.37, 0.10 and 0.03 of it (a compressed periphery shrinks little), and the
    kernel-3 maps of levels 0-4 needed up to 6.6, 6.4, 5.4, 1.8 and 0.4 pairs per input row;
    this plan has room for 1, 0.5, 0.25, 0.125 and 8, 8, 8, 4, 2. Data that do not fit grow it
    (`plan_pyramid(like=...)`), at the price of a compile.
    """
    caps = [capacity]
    for level in range(depth):
        factor = shrink if level == 0 else coarse_shrink
        caps.append(min(caps[-1], bucket(max(1, int(np.ceil(caps[-1] / factor))))))
    volume = 27

    def room(pairs, k):
        return plan_blocks(np.full(k, int(np.ceil(pairs / k)), np.int64))

    return PyramidPlan(tuple(caps), stem_kernel,
                       tuple(room((neighbours if level <= 1 else coarse_neighbours) * c, volume)
                             for level, c in enumerate(caps)),
                       tuple(room(1.25 * c, 8) for c in caps[:-1]))   # uneven offsets: a partial block each


def build_pyramid(coords: Int[Array, "n 4"], valid: Bool[Array, " n"], plan: PyramidPlan) -> Pyramid:
    """Every voxel set and kernel map of a U-Net (jit-able, `plan` static)."""
    coords, valid = jnp.asarray(coords, jnp.int32), jnp.asarray(valid, bool)
    if coords.shape[0] != plan.capacities[0]:
        raise ValueError(f"build_pyramid: {coords.shape[0]} rows, the plan was made for {plan.capacities[0]}")
    overflow = []
    levels = [(coords, valid)]
    for capacity in plan.capacities[1:]:
        c, v, o = downsample(*levels[-1], capacity=capacity)
        levels.append((c, v))
        overflow.append(o)

    stem = NeighbourTable(neighbour_table(coords, valid, coords, valid, kernel_size=plan.stem_kernel),
                          coords, valid, coords, valid)

    def sub_map(level, block, n_blocks):
        c, v = levels[level]
        if level == 0 and plan.stem_kernel >= 3:          # level 0's kernel-3 offsets are the stem's inner ones
            table = inner_table(stem.table, 3)
        else:
            table = neighbour_table(c, v, c, v, kernel_size=3)
        return pairs_from_table(table, n_in=c.shape[0], block=block, n_blocks=n_blocks,
                                in_coords=c, in_valid=v, out_coords=c, out_valid=v)

    submanifold = tuple(sub_map(k, *plan.submanifold[k]) for k in range(plan.depth + 1))
    down = []
    for k, (block, n_blocks) in enumerate(plan.down):
        (fc, fv), (cc, cv) = levels[k], levels[k + 1]
        table = neighbour_table(fc, fv, cc, cv, kernel_size=2, centred=False, stride=2)
        down.append(pairs_from_table(table, n_in=fc.shape[0], block=block, n_blocks=n_blocks,
                                     in_coords=fc, in_valid=fv, out_coords=cc, out_valid=cv))
    maps = [*submanifold, *down]
    overflowed = jnp.any(jnp.stack(overflow + [m.overflowed for m in maps]))
    return Pyramid(tuple(c for c, _ in levels), tuple(v for _, v in levels), stem, submanifold, tuple(down),
                   overflowed)
