"""CSF's programs: the pipeline's stages jitted on padded buffers and particle grids, and the
canonical shapes they are padded to, so a machine compiles them for a few shapes and keeps
them across processes (`gfjax.aot`).

`filter_points` is the whole pipeline for one padded point buffer, jitted; it is correct
under `jax.vmap` (a batch of tiles padded to one capacity and one grid shape). `gfjax.csf.filter`
runs the same stages as stored programs: `point_surface`, then steps 2-4 as three programs
(`start_cloth`, `advance_cloth` a chunk of the simulation at a time, `finish_cloth`:
`drop_cloth_in_chunks`), so that a progress bar moves between chunks (a program with a host
callback could not be stored), then `classify`.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from gfjax import aot
from gfjax._types import Mask, PointMask, Points, Raster
from gfjax.csf import cloth, stages
from gfjax.csf.cloth import ClothState, simulate
from gfjax.csf.config import BUFFER_PX, CLOTH_START_M, Config, Params
from gfjax.csf.wavefront import layout
from gfjax.tiling.buckets import canonical_capacity, canonical_side

__all__ = ["TileDiagnostics", "Anchor", "Surface", "WARM_SIDES", "CHUNK_SLOTS", "canonical_grid", "canonical_points",
           "grid_shape", "point_surface", "drop_cloth", "start_cloth", "advance_cloth", "finish_cloth", "chunk_blocks",
           "drop_cloth_in_chunks", "classify", "filter_points"]


class TileDiagnostics(NamedTuple):
    """The arrays of the jitted pipeline on one padded buffer (CSF's one tile: `filter_points`),
    particle grid `[j, i]` (row 0 = SOUTH); `Diagnostics` is what `filter` makes of them.

    Attributes:
      cloth_u: final cloth in the inverted frame `(h, w)` [m].
      surface_u: nearest-point surface after gap filling `(h, w)` [m].
      movable: particles that never touched the surface, bool `(h, w)`.
      exists: particles of this cloud's grid (False on padding), bool `(h, w)`.
      steps: simulation steps run, int32 scalar.
    """

    cloth_u: Raster
    surface_u: Raster
    movable: Mask
    exists: Mask
    steps: Int[Array, ""]


class Anchor(NamedTuple):
    """Where a cloth starts, when not at its own points: a survey's window lays its cloth on
    the survey's lattice and drops it from the survey's height, as one file of the whole survey
    would.

    Attributes:
      corner_m: float32 `(2,)` local x, y of a particle lattice corner, at or below every point
        (the cloth's south-west particle is `BUFFER_PX` cells beyond it) [m].
      top_u: float32 `()` the inverted height the cloth starts `CLOTH_START_M` above [m].
    """

    corner_m: Float[Array, 2]
    top_u: Float[Array, ""]


# Up to this many particles a side, grids are rounded to few sides (compiling dominates a small
# cloud's run, and `warm` compiles every pair of them); beyond, to multiples of `_LARGE_STEP` (a
# large cloud's run dominates its compile, and each padded particle costs every step).
WARM_SIDES = (128, 192, 256, 384, 512)
_LARGE_STEP = 64
# Slot updates (`wavefront.Layout`: rows x lanes per block) in one `advance_cloth` call of a
# progress bar's run: 0.1-0.3 s on a CPU core pair (30-80 ns a slot and block), so the
# bar moves a few times a second and the calls between chunks cost nothing measurable.
CHUNK_SLOTS = 1 << 22
_FEW_POINTS_UP_TO = 1 << 18
_LARGE_POINT_STEP = 1 << 16


def canonical_grid(shape: tuple[int, int]) -> tuple[int, int]:
    """A particle grid `(h, w)` padded to a canonical one, so a machine compiles CSF for a few
    grids in its life, not one per cloud size: each side up to 512 rounded up to the next of
    `WARM_SIDES` (128, 192, 256, 384, 512: at most half as many particles again a side above
    128, where a cloth's run starts to count; squares would pad an elongated cloud many times
    over, and every padded particle costs every step), a larger side to a multiple of 64. The
    particles beyond the cloud's own grid do not exist for the simulation (`filter_points`):
    the labels are the unpadded grid's."""
    return tuple(_canonical_side(int(side)) for side in shape)


def _canonical_side(side: int) -> int:
    fitted = canonical_side(side, WARM_SIDES)
    return -(-side // _LARGE_STEP) * _LARGE_STEP if fitted is None else fitted


def canonical_points(n: int) -> int:
    """The point capacity a cloud of `n` points is padded to: `buckets.canonical_capacity` up to
    2^18 points, then a multiple of 2^16 (padded points are not valid: they change nothing)."""
    return canonical_capacity(n) if n <= _FEW_POINTS_UP_TO else -(-n // _LARGE_POINT_STEP) * _LARGE_POINT_STEP


def grid_shape(xyz: np.ndarray | jax.Array, valid: np.ndarray | jax.Array, *, cell_m: float,
               anchor: Anchor | None = None) -> tuple[int, int]:
    """Static particle grid `(h, w)` of a float32 point buffer (the same formula as traced)."""
    xy = np.asarray(xyz, np.float32)[np.asarray(valid, bool), :2]
    lo = xy.min(axis=0) if anchor is None else np.asarray(anchor.corner_m, np.float32)
    extent = (xy.max(axis=0) - lo).astype(np.float32)
    w, h = (np.floor(extent / np.float32(cell_m)) + 2 * BUFFER_PX).astype(np.int64)
    return int(h), int(w)


class Surface(NamedTuple):
    """What a buffer's points give the cloth (`point_surface`), particle grid `[j, i]` (row 0 = SOUTH).

    Attributes:
      heights: inverted height of each particle's nearest point `(h, w)` [m], before gap filling.
      has_point: particles that hold a point, bool `(h, w)`.
      exists: particles of this cloud's grid (False on padding), bool `(h, w)`.
      corner_m: float32 `(2,)` local x, y of the south-west particle [m].
      start_u: the inverted height the cloth starts at [m].
    """

    heights: Raster
    has_point: Mask
    exists: Mask
    corner_m: Float[Array, 2]
    start_u: Float[Array, ""]


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def point_surface(xyz: Points, valid: PointMask, anchor: Anchor | None = None, *, config: Config,
                  shape: tuple[int, int]) -> Surface:
    """Steps 1-2 of the module docstring on one padded buffer (arguments as `filter_points`)."""
    cell = jnp.float32(config.cell_m)
    xy, u = xyz[:, :2], -xyz[:, 2]
    big = jnp.asarray(jnp.inf, xyz.dtype)
    lo = jnp.min(jnp.where(valid[:, None], xy, big), axis=0) if anchor is None else anchor.corner_m
    hi = jnp.max(jnp.where(valid[:, None], xy, -big), axis=0)
    w_h = stages.grid_size(hi - lo, cell_m=config.cell_m)
    j, i = jnp.indices(shape)
    corner = lo - BUFFER_PX * cell
    heights, has_point = stages.particle_heights(xy - corner[None, :], u, valid, cell_m=config.cell_m, shape=shape)
    top_u = jnp.max(jnp.where(valid, u, -big)) if anchor is None else anchor.top_u
    return Surface(heights, has_point, (i < w_h[0]) & (j < w_h[1]), corner, top_u + jnp.float32(CLOTH_START_M))


@functools.partial(jax.jit, static_argnames="config")
def drop_cloth(surface: Surface, params: Params, *, config: Config) -> tuple[Raster, Raster, Mask, Int[Array, ""]]:
    """Steps 2-4 on a particle grid: gaps filled, the cloth dropped and its slopes smoothed.
    Reads no point, so one program serves every point count of a grid (`warm` compiles it for
    each canonical grid).

    Returns:
      `(cloth_u, surface_u, movable, steps)`: as `TileDiagnostics`.
    """
    filled = stages.scanline_fill(surface.heights, surface.has_point)
    state = simulate(filled, surface.exists, surface.start_u, params.time_step, config=config)
    return _smoothed(state, filled, surface.exists, config=config)


def _smoothed(state: ClothState, filled: Raster, exists: Mask, *,
              config: Config) -> tuple[Raster, Raster, Mask, Int[Array, ""]]:
    """Step 4 on the stopped cloth; `(cloth_u, surface_u, movable, steps)` as `drop_cloth`."""
    cloth_u, movable = state.u, state.movable
    if config.slope_smooth:
        cloth_u, movable = stages.smooth_slopes(cloth_u, movable, exists, filled)
    return cloth_u, filled, movable, state.steps


# `drop_cloth` as three programs (`cloth.start`, `cloth.advance`, `cloth.finish`), each
# compiled once per grid and kept across processes as `drop_cloth` would be: the same cloth,
# whichever chunks `advance_cloth` runs; between two chunks `filter` moves its progress bar.

@functools.partial(jax.jit, static_argnames="config")
def start_cloth(surface: Surface, params: Params, *, config: Config) -> tuple[Raster, cloth.Run]:
    """`drop_cloth` up to its simulation: `(surface_u, run)`, the gap-filled surface `(h, w)`
    [m] and the cloth before its first block (`cloth.Run`)."""
    filled = stages.scanline_fill(surface.heights, surface.has_point)
    return filled, cloth.start(filled, surface.exists, surface.start_u, params.time_step, config=config)


@functools.partial(jax.jit, static_argnames="config", donate_argnums=0)
def advance_cloth(run: cloth.Run, until: Int[Array, ""], *, config: Config) -> cloth.Run:
    """`cloth.advance`: blocks until the cloth stops or block `until` (int32 scalar, a block
    counter; `cloth.NO_LIMIT`: to the stop) is next.
    `run` is donated: the result is written into its buffers, so one snapshot ring is ever
    held (`Config.memory_estimates`); the caller must not use `run` again."""
    return cloth.advance(run, until, config=config)


@functools.partial(jax.jit, static_argnames="config")
def finish_cloth(run: cloth.Run, filled: Raster, exists: Mask, *,
                 config: Config) -> tuple[Raster, Raster, Mask, Int[Array, ""]]:
    """`drop_cloth` from its stopped simulation (`filled`: `start_cloth`'s surface, `exists`:
    `Surface.exists`): slopes smoothed; returns as `drop_cloth`."""
    return _smoothed(cloth.finish(run), filled, exists, config=config)


def chunk_blocks(shape: tuple[int, int]) -> int:
    """Blocks in one `advance_cloth` call of a progress bar's run on a particle grid `shape`:
    `CHUNK_SLOTS` slot updates, at least one block."""
    lay = layout(shape)
    return max(1, CHUNK_SLOTS // (lay.rows * lay.lanes))


def drop_cloth_in_chunks(surface: Surface, params: Params, *, config: Config,
                         progress: bool = False) -> tuple[Raster, Raster, Mask, Int[Array, ""]]:
    """`drop_cloth` (same arguments and results, bit for bit) through the program store
    (`gfjax.aot`): `start_cloth`, `advance_cloth`, `finish_cloth`. Without `progress`, one
    `advance_cloth` call runs the simulation to its stop; with it, calls of `chunk_blocks`
    blocks each, and a progress bar on stderr between them (`_advance_with_bar`)."""
    filled, run = aot.call(start_cloth, surface, params, config=config)
    if progress:
        run = _advance_with_bar(run, tuple(surface.heights.shape), config)
    else:
        run = aot.call(advance_cloth, run, np.int32(cloth.NO_LIMIT), config=config)
    return aot.call(finish_cloth, run, filled, surface.exists, config=config)


def _advance_with_bar(run: cloth.Run, shape: tuple[int, int], config: Config) -> cloth.Run:
    """`run` advanced to its stop a chunk at a time, a tqdm bar moved after each chunk: blocks
    run, of the blocks a run to the cap takes (`cloth.blocks_to_cap`: the time left is the
    time to the cap), and the steps complete beside them; a cloth that settles before the cap
    completes the bar there, which says at which step."""
    from tqdm.auto import tqdm

    iterations, chunk = config.iterations, chunk_blocks(shape)
    with tqdm(total=cloth.blocks_to_cap(shape, iterations=iterations), desc="csf cloth", unit="block",
              postfix=f"step 0/{iterations}") as bar:
        block, stopped = 0, False                   # (a disabled bar counts nothing: TQDM_DISABLE)
        while not stopped:
            run = aot.call(advance_cloth, run, np.int32(block + chunk), config=config)
            block, stopped, last_step = (int(v) for v in jax.device_get((run.block, run.carry.stopped,
                                                                            run.carry.last_step)))
            if stopped and last_step + 1 < iterations:
                bar.total = block
                bar.set_postfix_str(f"settled at step {last_step + 1}/{iterations}", refresh=False)
            else:
                bar.set_postfix_str(f"step {cloth.steps_done(block, shape, iterations=iterations)}/{iterations}",
                                    refresh=False)
            bar.update(block - bar.n)
    return run


@functools.partial(jax.jit, static_argnames="config")
def classify(xyz: Points, valid: PointMask, corner_m: Float[Array, 2], cloth_u: Raster, params: Params, *,
             config: Config) -> PointMask:
    """Step 5: ground where a valid point lies within `params.class_threshold_m` of the cloth
    (`corner_m`: the south-west particle, `Surface.corner_m`)."""
    gap = stages.height_above_cloth(xyz[:, :2] - corner_m[None, :], -xyz[:, 2], cloth_u, cell_m=config.cell_m)
    return valid & stages.is_ground(gap, params.class_threshold_m)


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def filter_points(xyz: Points, valid: PointMask, params: Params, anchor: Anchor | None = None, *, config: Config,
                  shape: tuple[int, int]) -> tuple[PointMask, TileDiagnostics]:
    """CSF on one padded buffer of points: `point_surface`, `drop_cloth`, `classify`.

    Args:
      xyz: local coordinates `(n, 3)` float32 [m]; rows with `~valid` are ignored.
      valid: points that take part, bool `(n,)`; at least one must be True.
      params: traced class threshold and time step.
      anchor: the cloth's lattice corner and starting height (`Anchor`); default: the valid
        points' minimum x, y and highest inverted height.
      config: static settings.
      shape: static particle grid `(h, w)`, at least `grid_shape(xyz, valid)` (larger pads).

    Returns:
      `(ground, diagnostics)`: bool `(n,)` (False where `~valid`) and `TileDiagnostics`.
    """
    surface = point_surface(xyz, valid, anchor, config=config, shape=shape)
    cloth_u, filled, movable, steps = drop_cloth(surface, params, config=config)
    ground = classify(xyz, valid, surface.corner_m, cloth_u, params, config=config)
    return ground, TileDiagnostics(cloth_u, filled, movable, surface.exists, steps)
