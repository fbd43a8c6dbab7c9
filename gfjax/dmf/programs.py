"""DMF's compiled programs: each run through the program store (`gfjax.aot`), and prepared ahead
from the specs of its canonical shapes (`filter.warm`, a worker thread of `filter.prepare`).

- the raster stages of steps 4-6 (`stages.raster_stages`) on one padded tile, or vmapped over a
  batch of tiles (`batched_stages`): `raster_tile`, `raster_batch`, `prefetch_raster`;
- the basal loop of step 3 (`basal.basal_layer`) on nodes padded to a canonical capacity:
  `basal_layer`, `prefetch_basal`;
- step 7's point programs: the M-nearest rule's marks (`mark_ground`) and the height rule's
  surface fill and test (`height_test`, `prefetch_height_rule`).

A call and its prefetch name the same function with the same static arguments (taken from the
`Config` here, in one place), so the program `warm` prepares is the one a filter runs.
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from gfjax import aot
from gfjax.dmf import basal as basal_lib
from gfjax.dmf import stages
from gfjax.dmf.config import Config
from gfjax.raster import domain_mask, inpaint_nearest, replicate_edges, sample_bilinear
from gfjax.tiling.buckets import canonical_capacity

__all__ = ["stage_options", "batched_stages", "raster_tile", "raster_batch", "prefetch_raster", "basal_layer",
           "prefetch_basal", "mark_ground", "height_test", "prefetch_height_rule"]


def stage_options(config: Config) -> dict:
    """The static keyword arguments of `stages.raster_stages` for a `Config`."""
    return dict(max_filter_px=config.max_filter_px, max_close_px=config.close_max_px // 2,
                border_patches=config.border_patches, hole_test=config.hole_test, close_all=config.close_all)


@functools.partial(jax.jit, static_argnames=("max_filter_px", "max_close_px", "border_patches", "hole_test",
                                             "close_all"))
def batched_stages(z, layer, valid, inside, cell_m, rc_min_share, **static) -> stages.RasterStages:
    """`stages.raster_stages` vmapped over a batch `(b, h, w)` of padded tiles sharing W."""
    return jax.vmap(lambda a, b, c, d: stages.raster_stages(a, b, c, d, cell_m, rc_min_share, **static))(
        z, layer, valid, inside)


def raster_tile(z: np.ndarray, layer: np.ndarray, valid: np.ndarray, inside: np.ndarray, cell_m: np.float32,
                rc_min_share: np.float32, config: Config) -> stages.RasterStages:
    """Steps 4-6 on one padded tile (`stages.raster_stages`), dispatched without waiting.

    Args:
      z, layer, valid, inside: float32, int32, bool, bool `(h, w)` (a canonical shape).
      cell_m: W [m] and rc_min_share: float32 scalars (numpy: no conversion program runs).
      config: the stages' static options (`stage_options`).
    """
    return aot.call(stages.raster_stages, z, layer, valid, inside, cell_m, rc_min_share, **stage_options(config))


def raster_batch(z: np.ndarray, layer: np.ndarray, valid: np.ndarray, inside: np.ndarray, cell_m: np.float32,
                 rc_min_share: np.float32, config: Config) -> stages.RasterStages:
    """`raster_tile` on a batch `(b, h, w)` of padded tiles sharing W (`batched_stages`); every
    field gains a leading batch axis."""
    return aot.call(batched_stages, z, layer, valid, inside, cell_m, rc_min_share, **stage_options(config))


def prefetch_raster(shape: tuple[int, int], config: Config, *, batch: int = 0) -> None:
    """Load, or compile and store, the program `raster_tile` runs on a tile of padded `shape`
    (`batch` 0), or `raster_batch` on `batch` such tiles."""
    spec = jax.ShapeDtypeStruct
    lead = (batch,) if batch else ()
    specs = (spec((*lead, *shape), np.float32), spec((*lead, *shape), np.int32), spec((*lead, *shape), np.bool_),
             spec((*lead, *shape), np.bool_), spec((), np.float32), spec((), np.float32))
    aot.prefetch(batched_stages if batch else stages.raster_stages, *specs, **stage_options(config))


def basal_layer(xyz: np.ndarray, index: np.ndarray, valid: np.ndarray, sink_cap_m: np.float32,
                config: Config) -> basal_lib.BasalLayer:
    """Step 3's loop (`basal.basal_layer`) on nodes padded to a canonical capacity: xyz float32
    `(cap, 3)`, the cylinder table's index int32 and valid bool `(cap, basal_table_width)`,
    sink_cap_m float32 [m]; `config` gives its stop rule and iteration cap."""
    return aot.call(basal_lib.basal_layer, xyz, index, valid, sink_cap_m, stop=config.basal_stop,
                    max_iter=config.basal_max_iter)


def prefetch_basal(capacity: int, config: Config) -> None:
    """Load, or compile and store, the program `basal_layer` runs on `capacity` nodes."""
    spec = jax.ShapeDtypeStruct
    width = config.basal_table_width
    aot.prefetch(basal_lib.basal_layer, spec((capacity, 3), np.float32), spec((capacity, width), np.int32),
                 spec((capacity, width), np.bool_), spec((), np.float32), stop=config.basal_stop,
                 max_iter=config.basal_max_iter)


@functools.partial(jax.jit, static_argnames="n_points")
def _mark_ground(nearest: Int[Array, " n"], node_ground: Bool[Array, " s"], taken: Int[Array, "g m"],
                 *, n_points: int) -> Bool[Array, " n"]:
    """The program of `mark_ground`."""
    hit = jnp.zeros(n_points + 1, bool).at[taken.reshape(-1)].set(True)[:n_points]
    return hit & node_ground[nearest]


def mark_ground(nearest: np.ndarray, node_ground: np.ndarray, taken: np.ndarray, *, n_points: int) -> Bool[Array, " n"]:
    """Ground = among the M nearest points of some TP_G, and own nearest node is a TP_G.

    Args:
      nearest: each point's 3D-nearest support node, int32 `(n,)`.
      node_ground: TP_G flag per node, bool `(s,)`.
      taken: the M nearest points of each TP_G, int32 `(g, M)`; `n_points` marks "none".
    """
    return aot.call(_mark_ground, nearest, node_ground, taken, n_points=n_points)


@jax.jit
def _fill_surface(surface: Float[Array, "h w"], valid: Bool[Array, "h w"], hw: Int[Array, " 2"]) -> Float[Array, "h w"]:
    """The support surface with its empty cells taken from the nearest node, on a raster padded
    to a canonical shape (the data in its south-west corner, `hw` rows and columns; the
    padding repeats the data's edges, so that sampling clamps there as on the unpadded one,
    and costs no nearest-cell search)."""
    return replicate_edges(inpaint_nearest(surface, valid, domain_mask(hw, surface.shape)), hw)


@jax.jit
def _height_test(filled: Float[Array, "h w"], points: Float[Array, "n 3"], cell_m: Float[Array, ""],
                 threshold_m: Float[Array, ""]) -> Bool[Array, " n"]:
    """`z - S(x, y) <= threshold_m` for points in local metres (x, y from the raster's
    south-west corner), S sampled bilinearly between the centres of cells of `cell_m` (traced:
    one program serves every W)."""
    s = sample_bilinear(filled, points[:, :2] / cell_m, cell_m=1.0)
    return points[:, 2] - s <= threshold_m


def height_test(surface: np.ndarray, valid: np.ndarray, hw: np.ndarray, points: np.ndarray, cell_m: np.float32,
                threshold_m) -> Bool[Array, " n"]:
    """The height rule on a support surface padded to a canonical shape: its empty cells filled
    (`_fill_surface`), then `z - S(x, y) <= threshold_m` for each point (`_height_test`).

    Args:
      surface, valid: float32 [m] and bool `(h, w)`, the data in the south-west corner.
      hw: int32 `(2,)` the data's rows and columns.
      points: float32 `(c, 3)` local [m], padded to a canonical capacity.
      cell_m: W [m]; threshold_m: [m]; float32 scalars.
    """
    filled = aot.call(_fill_surface, surface, valid, hw)
    return aot.call(_height_test, filled, points, cell_m, threshold_m)


def prefetch_height_rule(n_points: int, shape: tuple[int, int]) -> None:
    """Load the stored programs `height_test` will run (`gfjax.aot.prefetch`), for `n_points`
    points (padded: `canonical_capacity`) on a raster of padded `shape` (`shapes.raster_shape`)."""
    spec = jax.ShapeDtypeStruct
    aot.prefetch(_fill_surface, spec(shape, np.float32), spec(shape, np.bool_), spec((2,), np.int32))
    aot.prefetch(_height_test, spec(shape, np.float32), spec((canonical_capacity(n_points), 3), np.float32),
                 spec((), np.float32), spec((), np.float32))
