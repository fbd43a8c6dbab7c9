"""The package's sequential spring sweep, laid out as parallel wavefronts (Cloth.cpp `timeStep`).

The package relaxes springs in place, particle after particle in `p = j * w + i` order, each
particle walking its 16 springs in its neighbour-list order (`SPRINGS`): a one-sided
Gauss-Seidel sweep. Particle `p` touches itself and its 16 neighbours, all within 2 cells in
`i` and `j`, so two particles touch a common particle only when they are at most 4 apart in
`i` and `j` (and never at `(+-4, +-1)` or `(+-4, +-3)`: spring offsets differ by even `j` when
their `i` differ by 4). Hence on a wavefront `t = i + 4 j` no two particles touch a common
one, and any two that do lie on different wavefronts in the package's order. Sweeping the
wavefronts `t = 0, 1, ...` in turn, each vectorised over its particles, replays the package's
sweep exactly: the same float operations on the same values in the same order.

Slots. Particle `(j, i)` sits at row `p = t + REACH` and lane `j mod lanes` of a `(rows, lanes)`
slot array. Folding rows `j` and `j + lanes` onto one lane is safe when `4 lanes >= w + 2`: the
two never share a wavefront, and a spring never reaches a particle of another fold (see
`Layout`). A spring `(di, dj)` from slot `(p, l)` lands on `(p + di + 4 dj, (l + dj) mod lanes)`,
row offsets in `[-REACH, REACH]`, all 16 distinct.

Blocks. Wavefronts `PERIOD = 2 REACH + 1 = 21` or more apart touch disjoint rows, so the
21-row windows (blocks) centred on wavefronts `phase, phase + 21, phase + 42, ...` tile the
slot array: block `g` is slot rows `21 g + phase + [0, 21)`, its centre row (`+ REACH`) the
wavefront, its first row the row no later wavefront of this sweep touches. With `rows =
(groups + 1) * 21`, the same row of every block is one slice of the slots seen as
`(groups + 1, 21, width)`. `relax_block` relaxes the springs of every block's wavefront at
once, in place.

Halo and kinds. The slot arrays the simulation carries have `HALO = 4` extra lanes on each side
holding copies of the lanes at the other end (`add_halo`, `refresh_halo`), so that every lane
shift `dj` of a spring is a plain slice (XLA on CPU materialises every operand of a
concatenate, which a wrapped roll is). A slot's state is one int8: `EMPTY` (no particle of the
cloud's grid: springs to it are skipped), `FIXED` or `MOVABLE`.
"""
from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Bool, Int

__all__ = ["SPRINGS", "SKEW", "REACH", "PERIOD", "HALO", "EMPTY", "FIXED", "MOVABLE", "Layout", "layout",
           "add_halo", "refresh_halo", "relax_block"]

# A particle's 16 springs as (di, dj), in the order Cloth.cpp's constructor appends them to its
# neighbour list (the order `Particle::satisfyConstraintSelf` walks them).
SPRINGS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (1, -1), (1, 0), (0, 1), (1, 1),
           (-2, -2), (-2, 0), (-2, 2), (0, -2), (2, -2), (2, 0), (0, 2), (2, 2))
SKEW = 4                                     # wavefront t = i + SKEW * j
REACH = 2 + 2 * SKEW                         # largest row offset of a spring: 10
PERIOD = 2 * REACH + 1                       # rows of a block: 21
HALO = 4                                     # lanes wrapped on each side: 2 for the centre, 2 more for its springs
EMPTY, FIXED, MOVABLE = 0, 1, 2              # int8 kinds of a slot


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static map between the particle grid `(h, w)` and the slot array `(rows, lanes)`.

    Attributes:
      shape: grid `(h, w)`, `[j, i]`.
      lanes: slot lanes `min(ceil((w + 2) / 4), h + 2)`; a particle `(j, i)` is at lane
        `j mod lanes` and row `i + 4 j + REACH`. With `4 lanes >= w + 2`, a spring from a
        particle at lane `l` to a lane `l'` reached through the wrap holds either the true
        neighbour or no particle (the particle `j + dj + k lanes`, `k != 0`, would have
        `i + di - 4 k lanes` outside `[0, w)`); with `lanes >= h + 2` nothing folds.
      groups: blocks per phase, `ceil((n_wavefronts + REACH) / PERIOD)`, so that the last
        particle row is the first row of some block.
      rows: slot rows `(groups + 1) * PERIOD` (a block read at phase `PERIOD - 1` fits).
      last_group, last_phase: the block and phase whose first row is the last particle row: a
        sweep is complete once that block at that phase is done.
      to_slots: int32 `(rows * lanes,)` flat grid index of each slot (`h * w`: empty slot).
      from_slots: int32 `(h * w,)` flat slot index of each particle.
    """

    shape: tuple[int, int]
    lanes: int
    groups: int
    rows: int
    last_group: int
    last_phase: int
    to_slots: np.ndarray
    from_slots: np.ndarray

    def to_slot_array(self, grid: Array, fill) -> Array:
        """Grid `(h, w)` -> slots `(rows, lanes)`, `fill` in empty slots."""
        flat = jnp.concatenate([grid.reshape(-1), jnp.full((1,), fill, grid.dtype)])
        return flat[self.to_slots].reshape(self.rows, self.lanes)

    def to_grid(self, slots: Array) -> Array:
        """Slots `(>= last particle row + 1, lanes)` -> grid `(h, w)`."""
        return slots.reshape(-1)[self.from_slots].reshape(self.shape)

    def by_phase(self, slots: Array) -> Array:
        """Slots `(rows, lanes)` -> phase-major `(PERIOD, groups, lanes)`: `[r, g]` is row
        `g * PERIOD + r`, so the first rows of all blocks at one phase are one slice."""
        head = slots[: self.groups * PERIOD]
        return head.reshape(self.groups, PERIOD, self.lanes).transpose(1, 0, 2)


def blocks_in_flight(shape: tuple[int, int]) -> int:
    """Blocks of a particle grid `(h, w)` in flight at once, `Layout.groups`: about
    `(w + 4 h) / PERIOD`, so the snapshots the simulation keeps grow with the grid's side as
    well as its area (`gfjax.csf.config.Config.memory_estimates`)."""
    h, w = shape
    return -(-(w + SKEW * (h - 1) + REACH) // PERIOD)


@functools.lru_cache(maxsize=32)
def layout(shape: tuple[int, int]) -> Layout:
    """The `Layout` of a particle grid `(h, w)` (numpy, cached per shape)."""
    h, w = shape
    lanes = min(-(-(w + 2) // SKEW), h + 2)
    n_wavefronts = w + SKEW * (h - 1)
    groups = blocks_in_flight(shape)
    rows = (groups + 1) * PERIOD
    j, i = np.indices(shape)
    slot = (i + SKEW * j + REACH) * lanes + j % lanes
    to_slots = np.full(rows * lanes, h * w, np.int64)
    to_slots[slot.reshape(-1)] = np.arange(h * w)
    last_row = n_wavefronts - 1 + REACH
    return Layout(shape=(h, w), lanes=lanes, groups=groups, rows=rows,
                  last_group=last_row // PERIOD, last_phase=last_row % PERIOD,
                  to_slots=to_slots.astype(np.int32), from_slots=slot.reshape(-1).astype(np.int32))


def add_halo(a: Array) -> Array:
    """`(..., lanes)` -> `(..., lanes + 2 HALO)`: the lanes wrapped around by `HALO` on each side,
    so that every lane shift of a spring is a plain slice."""
    lanes = a.shape[-1]
    k = -(-HALO // lanes)
    tiled = jnp.concatenate([a] * (2 * k + 1), axis=-1)
    return tiled[..., k * lanes - HALO: k * lanes + lanes + HALO]


def refresh_halo(a: Array) -> Array:
    """Rewrite the halo lanes of a haloed array `(..., lanes + 2 HALO)` from its lanes (after the
    lanes changed); the same as `add_halo(a[..., HALO:-HALO])`, written in place."""
    lanes = a.shape[-1] - 2 * HALO
    if lanes < HALO:
        return add_halo(a[..., HALO: HALO + lanes])
    low = lax.slice_in_dim(a, lanes, lanes + HALO, axis=-1)            # lanes - HALO .. lanes - 1
    high = lax.slice_in_dim(a, HALO, 2 * HALO, axis=-1)                # lanes 0 .. HALO - 1
    a = lax.dynamic_update_slice_in_dim(a, low, 0, axis=-1)
    return lax.dynamic_update_slice_in_dim(a, high, lanes + HALO, axis=-1)


def relax_block(u: Array, kind: Array, live: Bool[Array, " g"], phase: Int[Array, ""], *,
                double_move: float, single_move: float) -> Array:
    """Relax the 16 springs of the wavefronts `PERIOD g + phase` (`Particle::satisfyConstraintSelf`).

    For every block `g` and lane `l` at once: the centre particle `p` (block row `REACH`, slot
    row `PERIOD g + phase + REACH`) walks its springs in `SPRINGS` order; spring `k = (di, dj)`
    reaches `q_k` at block row `REACH + di + 4 dj`, lane `l + dj`. With `gap = u_q - u_p`, a
    movable `p` moves by `c_p gap` and a movable `q_k` by `-c_q gap`, `c = double_move` when
    both ends are movable, `single_move` toward a fixed end (Particle.cpp). The far ends are 16
    distinct rows, each read and written once, and only `u_p` is carried from spring to spring:
    the walk is a `lax.scan` over the springs, reading each far row (for all blocks: one slice
    of the slots seen as `(groups + 1, PERIOD, width)`) and writing it back in place. The centre
    is also walked on the 2 halo lanes on each side (copies of lanes at the other end), so that
    each far row, shifted by `dj`, is a slice of the result.

    Args:
      u: heights `(rows, lanes + 2 HALO)` [m], slots with haloed lanes (`add_halo`),
        `rows = (groups + 1) * PERIOD`.
      kind: int8 slots, same shape: `EMPTY` (no particle of the cloud's grid: springs skipped),
        `FIXED` or `MOVABLE`.
      live: bool `(groups,)`: blocks to relax (the others are left as they are).
      phase: int32 scalar in `[0, PERIOD)`.
      double_move, single_move: static fractions (config.double_move / single_move).

    Returns:
      Heights, slots like `u`, after the centre particles' springs; halo lanes stale
      (`refresh_halo`).
    """
    rows, width = u.shape
    groups = rows // PERIOD - 1
    lanes = width - 2 * HALO
    centre = lanes + 4                                              # lanes -2 .. lanes + 1
    c = REACH
    far_rows = jnp.asarray([c + di + SKEW * dj for di, dj in SPRINGS], jnp.int32)
    far_shift = jnp.asarray([dj for _, dj in SPRINGS], jnp.int32)

    def blocked(a: Array) -> Array:
        return a.reshape(groups + 1, PERIOD, width)

    def start(row, dl) -> tuple:                                     # block row, lane dl
        r = phase + row
        return r // PERIOD, r % PERIOD, HALO + dl

    def window(a: Array, row, dl) -> Array:                          # (groups, centre)
        return lax.dynamic_slice(blocked(a), start(row, dl), (groups, 1, centre))[:, 0]

    kind_p = window(kind, c, -2)
    mov_p, has_p = (kind_p == MOVABLE) & live[:, None], (kind_p != EMPTY) & live[:, None]

    def spring(carry: tuple[Array, Array], x: tuple[Array, Array]) -> tuple[tuple[Array, Array], None]:
        p, out = carry
        row, dj = x
        q, kind_q = window(u, row, dj - 2), window(kind, row, dj - 2)
        mov_q, has_q = kind_q == MOVABLE, kind_q != EMPTY
        coef_p = jnp.where(mov_p & has_q, jnp.where(mov_q, double_move, single_move), 0.0).astype(u.dtype)
        coef_q = jnp.where(mov_q & has_p, jnp.where(mov_p, double_move, single_move), 0.0).astype(u.dtype)
        gap = q - p
        q_new = lax.dynamic_slice_in_dim(q - coef_q * gap, 2 - dj, lanes, axis=1)   # lanes 0 .. lanes-1
        out = lax.dynamic_update_slice(out, q_new[:, None], start(row, 0))
        return (p + coef_p * gap, out), None

    (p, out), _ = lax.scan(spring, (window(u, c, -2), blocked(u)), (far_rows, far_shift))
    return lax.dynamic_update_slice(out, p[:, None, 2: 2 + lanes], start(c, 0)).reshape(u.shape)
