"""The cloth simulation of CSF (Zhang et al. 2016, Sec. 2.2-2.3) as one jitted `lax.while_loop`.

Frame: the package's. The cloud is turned upside down (`u = -z`, metres), the cloth starts
0.05 m above the highest inverted point and falls toward decreasing `u` onto the inverted
surface `h` (the nearest point's `u` per particle, `stages.particle_heights`). Arrays are
`(h, w)` particle grids indexed `[j, i]`: `i` along +x, `j` along +y (row 0 = SOUTH, the
package's particle order `j * w + i`; diagnostics are flipped to north-up by the caller).

One step (Cloth.cpp `Cloth::timeStep`, `Cloth::terrCollision`; Particle.cpp):
1. Verlet: movable particles `u <- u + (1 - DAMPING)(u - u_old) - GRAVITY * dt**4`
   (the package scales gravity by dt^2 in `addForce` and again in `Particle::timeStep`).
2. Springs: every particle is tied to its 16 neighbours at offsets (1, 0), (0, 1), (1, +-1),
   (2, 0), (0, 2), (2, +-2) (both signs). Relaxing a spring moves two movable ends toward each
   other by `double_move(rigidness)` of their height gap each, or one movable end toward a
   fixed one by `single_move(rigidness)` (Particle.cpp `satisfyConstraintSelf`).
3. The largest height change of a movable particle over the step (Verlet plus springs).
4. Collision: a movable particle below `h` is put on `h` and fixed.
The loop stops after `iterations` steps, or after the collision of a step whose largest
displacement is in (0, 0.005) m: the package's cap and rule (CSF.cpp `do_cloth`).

Solver (`wavefront_sweep`). The package relaxes springs in place, particle after particle in
`j * w + i` order, each particle walking its 16 springs in its neighbour-list order: a one-sided
Gauss-Seidel sweep that carries a displacement along a whole row and up the whole grid within
one step, far stiffer than a parallel (Jacobi) sweep. That order is replayed exactly, as a
`lax.scan` over the wavefronts `t = i + 4 j` vectorised over `j`: particles on one wavefront
never touch a common particle, and every pair that does is met in the package's order. The
cloth therefore matches the package's to float32 rounding, step for step, and stops at the
same step.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import Mask, Raster
from gfjax.csf.config import (DAMPING, GRAVITY, STOP_DISPLACEMENT_M, Config, double_move,
                              single_move)

__all__ = ["ClothState", "SPRINGS", "wavefront_sweep", "relax_springs", "simulate"]

# A particle's 16 springs as (di, dj), in the order Cloth.cpp's constructor appends them to its
# neighbour list (the order `satisfyConstraintSelf` walks them).
SPRINGS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (1, -1), (1, 0), (0, 1), (1, 1),
           (-2, -2), (-2, 0), (-2, 2), (0, -2), (2, -2), (2, 0), (0, 2), (2, 2))
EXACT_SKEW = 4


@functools.lru_cache(maxsize=32)
def _skew_index(shape: tuple[int, int], skew: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Gather indices between the grid `[j, i]` and the skewed layout `[t, j]`, `t = i + skew j`.

    Returns:
      `(to_skew, from_skew, n_t)`: flat indices into the padded grid (`h * w` = a dummy cell)
      of shape `(n_t, h)`, flat indices into the skewed array of shape `(h, w)`, and `n_t`.
    """
    h, w = shape
    n_t = w + skew * (h - 1)
    t, j = np.indices((n_t, h))
    i = t - skew * j
    to_skew = np.where((i >= 0) & (i < w), j * w + i, h * w)
    jj, ii = np.indices((h, w))
    from_skew = (ii + skew * jj) * h + jj
    return to_skew.astype(np.int32), from_skew.astype(np.int32), n_t


def wavefront_sweep(u: Raster, movable: Mask, exists: Mask, *, rigidness: int, unroll: int = 1) -> Raster:
    """One pass of the package's spring relaxation, in wavefronts `t = i + 4 j`.

    The package walks particles in `j * w + i` order, each relaxing its 16 springs in place.
    Particle `p` touches `p` and its 16 neighbours; two particles whose touched sets overlap are
    at most 4 apart in `i` and `j`, and none is at `(4, -1)`. So the particles of a wavefront
    `t = i + 4 j` touch disjoint sets, and every overlapping pair is met in the package's order:
    the sweep is the package's, exactly (same operations on the same values in the same order).
    It costs `w + 4 (h - 1)` dependent scan steps, each vectorised over the `h` lanes `j`.

    Args:
      u: heights `(h, w)` [m] (`[j, i]`, row 0 south).
      movable, exists: bool `(h, w)`; fixed particles never move, springs to particles that do
        not exist (padding) are skipped.
      rigidness: static; sets `double_move` / `single_move` (Particle.h).
      unroll: static unroll factor of the scan (speed only).

    Returns:
      Heights `(h, w)` [m] after the pass.
    """
    both, single = double_move(rigidness), single_move(rigidness)
    skew = EXACT_SKEW
    h, w = u.shape
    to_skew, from_skew, n_t = _skew_index((h, w), skew)
    reach = 2 + 2 * skew                                   # largest |t| offset of a spring
    span = 2 * reach + 1                                    # rows t - reach .. t + reach

    def skewed(a: Array, fill) -> Array:                    # (n_t + 2 reach, h + 4)
        flat = jnp.concatenate([a.reshape(-1), jnp.full((1,), fill, a.dtype)])
        return jnp.pad(flat[to_skew], ((reach, reach), (2, 2)), constant_values=fill)

    su, sm, se = skewed(u, 0.0), skewed(movable, False), skewed(exists, False)

    def step(carry, x):
        rows_u, rows_m, rows_e = ([*c, xi] for c, xi in zip(carry, x))
        c = reach
        for di, dj in SPRINGS:
            r = c + di + skew * dj
            p, q = _lanes(rows_u[c], 0, h), _lanes(rows_u[r], dj, h)
            mov_p, mov_q = _lanes(rows_m[c], 0, h), _lanes(rows_m[r], dj, h)
            live = _lanes(rows_e[c], 0, h) & _lanes(rows_e[r], dj, h)
            gap = q - p
            coef_p = jnp.where(live & mov_p, jnp.where(mov_q, both, single), 0.0).astype(u.dtype)
            coef_q = jnp.where(live & mov_q, jnp.where(mov_p, both, single), 0.0).astype(u.dtype)
            rows_u[c] = rows_u[c] + jnp.pad(coef_p * gap, (2, 2))
            rows_u[r] = rows_u[r] - jnp.pad(coef_q * gap, (2 + dj, 2 - dj))
        out = (rows_u[0], rows_m[0], rows_e[0])
        return (tuple(rows_u[1:]), tuple(rows_m[1:]), tuple(rows_e[1:])), out[0]

    init = tuple(tuple(a[d] for d in range(span - 1)) for a in (su, sm, se))
    xs = tuple(a[span - 1:] for a in (su, sm, se))
    carry, done = lax.scan(step, init, xs, unroll=unroll)
    rows = jnp.concatenate([done, jnp.stack(carry[0])], axis=0)[reach:reach + n_t, 2:h + 2]
    return rows.reshape(-1)[from_skew]


def _lanes(line: Array, dl: int, n: int) -> Array:
    """`line[2 + dl : 2 + dl + n]` of a line padded by 2 lanes on each side."""
    return lax.slice_in_dim(line, 2 + dl, 2 + dl + n, axis=0)


def relax_springs(u: Raster, movable: Mask, exists: Mask, *, rigidness: int, unroll: int = 1) -> Raster:
    """One step's spring relaxation (Cloth.cpp `timeStep`, the `satisfyConstraintSelf` loop)."""
    return wavefront_sweep(u, movable, exists, rigidness=rigidness, unroll=unroll)


class ClothState(NamedTuple):
    """Loop state of the simulation (one cloth; vmap adds a leading axis).

    Attributes:
      u: particle heights in the inverted frame, `(h, w)` [m].
      u_old: heights one step earlier (Verlet), `(h, w)` [m].
      movable: particles still falling, bool `(h, w)`.
      max_step_m: largest movable-particle displacement of the last step [m].
      steps: steps done, int32 scalar.
    """

    u: Raster
    u_old: Raster
    movable: Mask
    max_step_m: Float[Array, ""]
    steps: Int[Array, ""]


def _displacement_stops(max_step_m: Float[Array, ""]) -> Bool[Array, ""]:
    """The package's early stop: `maxDiff != 0 && maxDiff < 0.005` (CSF.cpp `do_cloth`)."""
    return (max_step_m != 0) & (max_step_m < STOP_DISPLACEMENT_M)


@functools.partial(jax.jit, static_argnames="config")
def simulate(heights: Raster, exists: Mask, start_u: Float[Array, ""], time_step: Float[Array, ""],
             *, config: Config) -> ClothState:
    """Drop the cloth onto the inverted surface.

    Args:
      heights: inverted surface `h` per particle, `(h, w)` [m] (filled everywhere it exists).
      exists: particles of this cloth, bool `(h, w)` (False on padding for batched tiles).
      start_u: initial cloth height, scalar [m] (highest inverted point + 0.05 m).
      time_step: Verlet time step (traced); gravity moves a free particle `0.2 dt^4` per step.
      config: static; `iterations`, `rigidness`, `scan_unroll` are used.

    Returns:
      The final `ClothState`; `steps` says how many steps ran (<= `config.iterations`).
    """
    dtype = heights.dtype
    accel = (-GRAVITY * time_step ** 4).astype(dtype)
    u0 = jnp.where(exists, start_u.astype(dtype), heights)
    state = ClothState(u=u0, u_old=u0, movable=exists, max_step_m=jnp.asarray(jnp.inf, dtype),
                       steps=jnp.int32(0))

    def cond(s: ClothState) -> Bool[Array, ""]:
        return (s.steps < config.iterations) & ~_displacement_stops(s.max_step_m)

    def body(s: ClothState) -> ClothState:
        u = jnp.where(s.movable, s.u + (s.u - s.u_old) * (1.0 - DAMPING) + accel, s.u)
        u_old = jnp.where(s.movable, s.u, s.u_old)
        u = relax_springs(u, s.movable, exists, rigidness=config.rigidness, unroll=config.scan_unroll)
        max_step = jnp.max(jnp.where(s.movable, jnp.abs(u - s.u), 0.0))
        hit = s.movable & (u < heights)
        return ClothState(u=jnp.where(hit, heights, u), u_old=u_old, movable=s.movable & ~hit,
                          max_step_m=max_step, steps=s.steps + 1)

    return lax.while_loop(cond, body, state)
