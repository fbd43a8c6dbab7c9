"""The cloth simulation of CSF (Zhang et al. 2016, Sec. 2.2-2.3), replayed exactly and pipelined.

Frame: the package's. The cloud is turned upside down (`u = -z`, metres), the cloth starts
0.05 m above the highest inverted point and falls toward decreasing `u` onto the inverted
surface `h` (the nearest point's `u` per particle, `stages.particle_heights`). Arrays are
`(h, w)` particle grids indexed `[j, i]`: `i` along +x, `j` along +y (row 0 = SOUTH, the
package's particle order `j * w + i`; diagnostics are flipped to north-up by the caller).

One step (Cloth.cpp `Cloth::timeStep`, `Cloth::terrCollision`; Particle.cpp):
1. Verlet: movable particles `u <- u + (1 - DAMPING)(u - u_old) - GRAVITY * dt**4`
   (the package scales gravity by dt^2 in `addForce` and again in `Particle::timeStep`).
2. Springs: one in-place sweep over the particles in `j * w + i` order, each relaxing its 16
   springs (`wavefront.relax_block`; Particle.cpp `satisfyConstraintSelf`).
3. The largest height change of a movable particle over the step (Verlet plus springs).
4. Collision: a movable particle below `h` is put on `h` and fixed.
The loop stops after `iterations` steps, or after the collision of a step whose largest
displacement is in (0, 0.005) m: the package's cap and rule (CSF.cpp `do_cloth`). It also
stops at a step that begins with no movable particle, and at the second of two steps in a
row that moved no particle (a time step so small that float32 loses gravity's pull: the
second step starts from the state the first did, so every later one repeats it): the
package runs on to its cap from there, but no later step changes anything (only `steps`
differs).

Pipelining. The sweep is a sequence of wavefronts `t = i + 4 j` (`gfjax.csf.wavefront`), and a
particle's steps 3-4 and the next step's 1 depend on that particle alone. So step `s + 1` may
start on the first wavefronts while step `s` is still sweeping the later ones, as long as it
stays `PERIOD = 21` wavefronts behind: then the two never touch a common particle out of the
package's order. At iteration `T = PERIOD * b + phase` the loop relaxes every wavefront
`t = PERIOD * g + phase`, for step `b - g` (blocks `g = 0 .. groups - 1`), as one vectorised
`relax_block`; then finishes the step of each block's first row (`t - REACH`: no later
wavefront of that step touches it): displacement, collision, the next step's Verlet. A step
takes `PERIOD` iterations instead of `w + 4 h`, and about `groups = (w + 4 h) / 21` steps are
in flight. The result is the package's cloth, step for step, to float32 rounding.

The stopping rule needs a step's largest displacement, known once its last row is finished;
by then later steps have moved the first rows. Each finished row is therefore also written
to a ring of `groups` snapshots, from which the cloth at the stopping step is read back.
Cost: `PERIOD * (steps + groups)` iterations of `groups * lanes` particles each (about
`h * w / 21 * 1.25` for a square grid); memory: the ring holds `groups + 1` copies of the grid.

Chunks. `start`, `advance` and `finish` are `simulate` cut at block boundaries: `advance(run,
until)` runs blocks until the cloth stops or block `until` is next, and returns the whole loop
state (`Run`: slots, ring, the stopping rule's state, the block counter) for the next call.
The blocks, their order and the stopping rule are `simulate`'s, so the cloth, its stopping
step and its fixed particles are too, however the blocks are cut; between calls a caller may
draw a progress bar (`gfjax.csf.filter`). Step `s` is complete after block `s + last_group`
(`steps_done`); a run to the cap takes `blocks_to_cap` blocks.

Batches (`jax.vmap`): the cloths share the block counter, so every slice stays a slice (a
batched counter would turn them into gathers), and the loop runs until the last cloth stops; a
stopped cloth is frozen (no block is live, its ring writes go to a spare slot).
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jaxtyping import Array, Bool, Float, Int

from gfjax._types import Mask, Raster
from gfjax.csf.config import DAMPING, GRAVITY, STOP_DISPLACEMENT_M, Config, double_move, single_move
from gfjax.csf.wavefront import EMPTY, FIXED, HALO, MOVABLE, PERIOD, Layout, add_halo, layout, refresh_halo, relax_block

__all__ = ["ClothState", "Run", "NO_LIMIT", "simulate", "start", "advance", "finish", "steps_done", "blocks_to_cap", "sweep"]

NO_LIMIT = 2**31 - 1                          # an `advance` limit never reached: run to the stop


class ClothState(NamedTuple):
    """The cloth when the simulation stops (one cloth; vmap adds a leading axis).

    Attributes:
      u: particle heights in the inverted frame, `(h, w)` [m].
      movable: particles still falling, bool `(h, w)`.
      max_step_m: largest movable-particle displacement of the last step [m].
      steps: steps run (<= the cap), int32 scalar.
    """

    u: Raster
    movable: Mask
    max_step_m: Float[Array, ""]
    steps: Int[Array, ""]


class _Carry(NamedTuple):
    """Loop state of one cloth (the block counter `b`, shared by a batch, is kept apart).
    Slot arrays `(rows, lanes + 2 HALO)`; phase-major `(PERIOD, groups, lanes)`."""

    u: Array                                  # slots (haloed lanes), heights [m]
    kind: Array                               # slots (haloed lanes), int8 EMPTY / FIXED / MOVABLE
    u_prev: Array                             # phase-major, height at the start of the step [m]
    hit_step: Array                           # phase-major int32, step of collision (cap: none)
    ring: Array                               # (groups + 1, PERIOD, groups, lanes) finished rows [m]
    max_step: Array                           # (groups,) running max displacement per step [m]
    live: Array                               # (groups,) a particle was movable at the step's start
    stopped: Bool[Array, ""]
    still: Bool[Array, ""]                    # the last step checked moved no particle
    last_step: Int[Array, ""]
    last_max: Float[Array, ""]


def _displacement_stops(max_step_m: Float[Array, ""]) -> Bool[Array, ""]:
    """The package's early stop: `maxDiff != 0 && maxDiff < 0.005` (CSF.cpp `do_cloth`)."""
    return (max_step_m != 0) & (max_step_m < STOP_DISPLACEMENT_M)


def _first_rows(slots: Array, phase: Int[Array, ""], groups: int) -> Array:
    """The slot rows `PERIOD g + phase`, `(groups, width)`."""
    blocked = slots.reshape(groups + 1, PERIOD, slots.shape[-1])
    return lax.dynamic_slice_in_dim(blocked, phase, 1, axis=1)[:groups, 0]


def _set_first_rows(slots: Array, rows: Array, phase: Int[Array, ""]) -> Array:
    """Write `rows` `(groups, width)` to the slot rows `PERIOD g + phase` of `slots` `(rows, width)`."""
    groups = rows.shape[0]
    blocked = slots.reshape(groups + 1, PERIOD, slots.shape[-1])
    return lax.dynamic_update_slice(blocked, rows[:, None], (0, phase, 0)).reshape(slots.shape)


def _phase(lay: Layout, heights: Array, accel: Float[Array, ""], *, iterations: int, rigidness: int,
           block: Int[Array, ""], phase: Int[Array, ""], c: _Carry) -> _Carry:
    """Iteration `T = PERIOD * block + phase`: relax the wavefronts `PERIOD g + phase`, finish
    the blocks' first rows. A stopped cloth is left as it is (for batches that run on)."""
    groups, lanes = lay.groups, lay.lanes
    group = jnp.arange(groups, dtype=jnp.int32)
    step = block - group                                            # (groups,) step of each block
    active = (step >= 0) & (step < iterations) & ~c.stopped

    slots_u = relax_block(c.u, c.kind, active, phase, double_move=double_move(rigidness),
                          single_move=single_move(rigidness))
    # Finish this step on each block's first row (Cloth.cpp: maxDiff, terrCollision, timeStep).
    kind0 = _first_rows(c.kind, phase, groups)[:, HALO: HALO + lanes]
    u0 = _first_rows(slots_u, phase, groups)[:, HALO: HALO + lanes]
    prev0, h0 = c.u_prev[phase], heights[phase]
    mov0 = (kind0 == MOVABLE) & active[:, None]
    moved = jnp.max(jnp.where(mov0, jnp.abs(u0 - prev0), 0.0), axis=1)
    any_movable = jnp.any(mov0, axis=1)
    hit = mov0 & (u0 < h0)
    u0 = jnp.where(hit, h0, u0)
    free = mov0 & ~hit
    slot = block % groups
    scratch = jnp.where(c.stopped, groups, slot)              # a stopped cloth writes to the spare slot
    ring = lax.dynamic_update_slice(c.ring, u0[None, None], (scratch, phase, 0, 0))
    hit_step = lax.dynamic_update_slice(
        c.hit_step, jnp.where(hit, step[:, None], c.hit_step[phase])[None], (phase, 0, 0))
    u_prev = lax.dynamic_update_slice(c.u_prev, jnp.where(free, u0, prev0)[None], (phase, 0, 0))
    u0 = jnp.where(free, u0 + (u0 - prev0) * (1.0 - DAMPING) + accel, u0)   # next step's Verlet
    slots_u = refresh_halo(slots_u)
    # The first rows `PERIOD g + phase` are `[g, phase]` of the slots seen as
    # `(groups + 1, PERIOD, width)`: one slice.
    slots_u = _set_first_rows(slots_u, add_halo(u0), phase)
    slots_kind = _set_first_rows(c.kind, add_halo(jnp.where(hit, jnp.int8(FIXED), kind0)), phase)
    # Per-step displacement maxima; a step is done when its last particle row is finished.
    max_step = jnp.where(phase == 0, c.max_step.at[slot].set(0.0), c.max_step)
    max_step = max_step.at[step % groups].max(moved)
    live = jnp.where(phase == 0, c.live.at[slot].set(False), c.live)
    live = live.at[step % groups].max(any_movable)
    done = block - lay.last_group
    check = (phase == lay.last_phase) & (done >= 0) & (done < iterations) & ~c.stopped
    done_max = max_step[done % groups]
    # A step that began with no movable particle changes nothing, nor does any later one:
    # stopping there gives the cloth of the cap (the package runs on to the cap).
    # Two steps in a row that moved nothing: the second began where the first did (no
    # velocity, the same springs), so it is a fixed point.
    frozen = c.still & (done_max == 0)
    stop = check & (_displacement_stops(done_max) | ~live[done % groups] | frozen | (done == iterations - 1))
    return _Carry(u=slots_u, kind=slots_kind, u_prev=u_prev, hit_step=hit_step,
                  ring=ring, max_step=max_step, live=live, stopped=c.stopped | stop,
                  still=jnp.where(check, done_max == 0, c.still),
                  last_step=jnp.where(stop, done, c.last_step),
                  last_max=jnp.where(stop, done_max, c.last_max))


def _init(u: Raster, u_prev: Raster, movable: Mask, present: Mask, heights: Raster, *,
          iterations: int) -> tuple[_Carry, Array]:
    """Loop state before step 0's springs, and the surface in phase-major slots."""
    lay = layout(u.shape)
    groups, lanes, dtype = lay.groups, lay.lanes, u.dtype
    kind = jnp.where(movable, jnp.int8(MOVABLE), jnp.where(present, jnp.int8(FIXED), jnp.int8(EMPTY)))
    init = _Carry(
        u=add_halo(lay.to_slot_array(u, 0.0)), kind=add_halo(lay.to_slot_array(kind, jnp.int8(EMPTY))),
        u_prev=lay.by_phase(lay.to_slot_array(u_prev, 0.0)),
        hit_step=jnp.full((PERIOD, groups, lanes), iterations, jnp.int32),
        ring=jnp.zeros((groups + 1, PERIOD, groups, lanes), dtype), max_step=jnp.zeros(groups, dtype),
        live=jnp.zeros(groups, bool),
        stopped=jnp.array(False), still=jnp.array(False), last_step=jnp.int32(iterations - 1),
        last_max=jnp.asarray(jnp.inf, dtype))
    return init, lay.by_phase(lay.to_slot_array(heights, -jnp.inf))


def _block(heights: Array, accel: Float[Array, ""], c: _Carry, block: Int[Array, ""], *, lay: Layout,
           iterations: int, rigidness: int) -> _Carry:
    """The `PERIOD` iterations of one block counter."""
    phase = functools.partial(_phase, lay, heights, accel, iterations=iterations, rigidness=rigidness,
                              block=block)
    return lax.fori_loop(0, PERIOD, lambda k, cc: phase(phase=k, c=cc), c)


def _result(c: _Carry, movable: Mask, *, lay: Layout) -> ClothState:
    """The cloth at the stopping step, read back from the ring."""
    groups, lanes = lay.groups, lay.lanes
    group = jnp.arange(groups)
    final = c.ring[(c.last_step + group) % groups, :, group, :]          # (groups, PERIOD, lanes)
    u_end = lay.to_grid(final.reshape(groups * PERIOD, lanes))
    hit_step = c.hit_step.transpose(1, 0, 2).reshape(groups * PERIOD, lanes)
    fixed = lay.to_grid(hit_step) <= c.last_step
    return ClothState(u=u_end, movable=movable & ~fixed, max_step_m=c.last_max, steps=c.last_step + 1)


class Run(NamedTuple):
    """One cloth part way through its simulation, between two `advance` calls (a pytree of
    arrays: it stays on the device, and a program may take it, donated, and return the next).

    Attributes:
      carry: the loop state (`_Carry`: slots, snapshot ring, the stopping rule's state).
      block: the next block counter `b` (iterations `PERIOD b + phase` come next), int32 scalar.
      heights: the inverted surface in phase-major slots `(PERIOD, groups, lanes)` [m].
      accel: Verlet gravity term, scalar [m per step].
      movable: particles free to move at step 0, bool `(h, w)`.
    """

    carry: _Carry
    block: Int[Array, ""]
    heights: Array
    accel: Float[Array, ""]
    movable: Mask


def _start(u: Raster, u_prev: Raster, movable: Mask, present: Mask, heights: Raster, accel: Float[Array, ""], *,
           iterations: int) -> Run:
    """The `Run` before block 0 (arguments as `_run`)."""
    init, surface = _init(u, u_prev, movable, present, heights, iterations=iterations)
    return Run(carry=init, block=jnp.int32(0), heights=surface, accel=accel, movable=movable)


def _advance(run: Run, until: Int[Array, ""], *, iterations: int, rigidness: int) -> Run:
    """Blocks `run.block, run.block + 1, ...` until the cloth stops or block `until` is next."""
    body = functools.partial(_block, run.heights, run.accel, lay=layout(run.movable.shape), iterations=iterations,
                             rigidness=rigidness)
    block, c = lax.while_loop(lambda bc: ~bc[1].stopped & (bc[0] < until), lambda bc: (bc[0] + 1, body(bc[1], bc[0])),
                              (run.block, run.carry))
    return run._replace(carry=c, block=block)


def _finish(run: Run) -> ClothState:
    """The cloth at the stopping step (of a stopped `run`)."""
    return _result(run.carry, run.movable, lay=layout(run.movable.shape))


@functools.cache
def _runner(iterations: int, rigidness: int):
    """`run(u, u_prev, movable, present, heights, accel) -> ClothState`: steps 2-4 of step 0,
    then whole steps, until the cap or the stopping rule (`u`: heights after step 0's Verlet,
    `u_prev` before it). Under `jax.vmap` the cloths of a batch share the block counter (so
    every slice stays a slice) and the loop runs until the last one stops."""
    static = {"iterations": iterations, "rigidness": rigidness}

    @jax.custom_batching.custom_vmap
    def run(u, u_prev, movable, present, heights, accel):
        started = _start(u, u_prev, movable, present, heights, accel, iterations=iterations)
        return _finish(_advance(started, jnp.int32(NO_LIMIT), **static))

    @run.def_vmap
    def run_batched(axis_size, in_batched, *args):
        args = [a if batched else jnp.broadcast_to(a, (axis_size, *a.shape))
                for a, batched in zip(args, in_batched)]
        u, u_prev, movable, present, heights, accel = args
        lay = layout(u.shape[1:])
        init, surface = jax.vmap(functools.partial(_init, iterations=iterations))(
            u, u_prev, movable, present, heights)
        body = jax.vmap(functools.partial(_block, lay=lay, **static), in_axes=(0, 0, 0, None))
        _, c = lax.while_loop(lambda bc: jnp.any(~bc[1].stopped),
                              lambda bc: (bc[0] + 1, body(surface, accel, bc[1], bc[0])),
                              (jnp.int32(0), init))
        out = jax.vmap(functools.partial(_result, lay=lay))(c, movable)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return run


def _run(u: Raster, u_prev: Raster, movable: Mask, present: Mask, heights: Raster,
         accel: Float[Array, ""], *, iterations: int, rigidness: int) -> ClothState:
    """Steps 2-4 of step 0, then whole steps, until the cap or the stopping rule.

    Args:
      u: heights after step 0's Verlet `(h, w)` [m]; u_prev: heights before it [m].
      movable: particles free to move; present: particles of the cloud's grid. Bool `(h, w)`.
      heights: inverted surface `(h, w)` [m]; accel: Verlet gravity term [m per step].
      iterations, rigidness: static cap and spring stiffness.
    """
    return _runner(iterations, rigidness)(u, u_prev, movable, present, heights, accel)


@functools.partial(jax.jit, static_argnames="config")
def simulate(heights: Raster, exists: Mask, start_u: Float[Array, ""], time_step: Float[Array, ""],
             *, config: Config) -> ClothState:
    """Drop the cloth onto the inverted surface.

    Args:
      heights: inverted surface `h` per particle, `(h, w)` [m] (filled everywhere it exists).
      exists: particles of this cloth, bool `(h, w)` (False on padding for batched tiles).
      start_u: initial cloth height, scalar [m] (highest inverted point + 0.05 m).
      time_step: Verlet time step (traced); gravity moves a free particle `0.2 dt^4` per step.
      config: static; `iterations` and `rigidness` are used.

    Returns:
      The final `ClothState`; `steps` says how many steps ran (<= `config.iterations`).
    """
    u1, u0, accel = _dropped(heights, exists, start_u, time_step)
    return _run(u1, u0, exists, exists, heights, accel, iterations=config.iterations,
                rigidness=config.rigidness)


def _dropped(heights: Raster, exists: Mask, start_u: Float[Array, ""],
             time_step: Float[Array, ""]) -> tuple[Raster, Raster, Float[Array, ""]]:
    """`(u1, u0, accel)`: the cloth after and before step 0's Verlet, and gravity's term."""
    dtype = heights.dtype
    accel = (-GRAVITY * time_step ** 4).astype(dtype)
    u0 = jnp.where(exists, start_u.astype(dtype), heights)
    u1 = jnp.where(exists, u0 + (u0 - u0) * (1.0 - DAMPING) + accel, u0)     # step 0's Verlet
    return u1, u0, accel


# `simulate` a chunk of blocks at a time: `finish(advance(... advance(start(...), until_1) ...))`
# runs the very blocks `simulate` runs, in the same order, and gives its `ClothState`, however
# the blocks are cut; between two `advance` calls the caller may report progress.

@functools.partial(jax.jit, static_argnames="config")
def start(heights: Raster, exists: Mask, start_u: Float[Array, ""], time_step: Float[Array, ""], *,
          config: Config) -> Run:
    """The cloth of `simulate` (same arguments) before its first block, as a `Run`."""
    u1, u0, accel = _dropped(heights, exists, start_u, time_step)
    return _start(u1, u0, exists, exists, heights, accel, iterations=config.iterations)


@functools.partial(jax.jit, static_argnames="config")
def advance(run: Run, until: Int[Array, ""], *, config: Config) -> Run:
    """Run blocks until the cloth stops (the cap or the stopping rule, as `simulate`) or block
    `until` (int32 scalar, a block counter; `NO_LIMIT`: to the stop) would be next; a stopped
    `run` is returned as it is. `config`: as `start`'s."""
    return _advance(run, until, iterations=config.iterations, rigidness=config.rigidness)


@jax.jit
def finish(run: Run) -> ClothState:
    """The final `ClothState` of a stopped `run` (`run.carry.stopped`): `simulate`'s."""
    return _finish(run)


def steps_done(block: int, shape: tuple[int, int], *, iterations: int) -> int:
    """Steps whose sweep is complete once blocks `0 .. block - 1` ran, on a grid `shape`
    `(h, w)` (host ints): step `s` finishes at block `s + last_group` (`Layout`), so the
    first `last_group` blocks (the pipeline filling) finish none."""
    return min(max(block - layout(shape).last_group, 0), iterations)


def blocks_to_cap(shape: tuple[int, int], *, iterations: int) -> int:
    """Blocks a cloth on a grid `shape` `(h, w)` runs when it stops at the cap `iterations`:
    one per step, and `last_group` more while the pipeline fills (host int)."""
    return iterations + layout(shape).last_group


@functools.partial(jax.jit, static_argnames="rigidness")
def sweep(u: Raster, movable: Mask, exists: Mask, *, rigidness: int) -> Raster:
    """One spring sweep alone (Cloth.cpp `timeStep`'s `satisfyConstraintSelf` loop).

    Args:
      u: heights `(h, w)` [m]; movable, exists: bool `(h, w)` (fixed particles never move,
        springs to particles that do not exist are skipped).
      rigidness: static; sets `double_move` / `single_move` (Particle.h).

    Returns:
      Heights `(h, w)` [m] after the sweep (the pipelined loop, one step, no gravity or surface).
    """
    no_surface = jnp.full(u.shape, -jnp.inf, u.dtype)
    state = _run(u, u, movable & exists, exists, no_surface, jnp.zeros((), u.dtype), iterations=1,
                 rigidness=rigidness)
    return state.u
