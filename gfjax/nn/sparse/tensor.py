"""`SparseTensor`: occupied voxels with features, padded to a static capacity.

Points become voxels by `voxelize` (integer grid `floor(xyz / voxel_m)`, features averaged
per voxel) and voxel features go back to the points by `devoxelize` (each point takes its
own voxel's row: nearest projection, no trilinear weights).
"""
from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.typing import ArrayLike
from jaxtyping import Array, Bool, Float, Int

from gfjax.nn.sparse import keys as K


class SparseTensor(eqx.Module):
    """Features on occupied voxels.

    Attributes:
      coords: `(n, 4)` int32 `(b, i, j, k)`: batch index, then grid indices at this tensor's
        stride (a voxel of edge `stride * voxel_m`).
      feats: `(n, c)` features; rows where `~valid` are 0.
      valid: `(n,)` bool, the rows that hold a voxel; the rest pad to the capacity `n`.
      stride: static, the voxel edge in units of the finest grid (1, 2, 4, ...).
      batch_size: static, the number of batch indices `b` in use (`0 <= b < batch_size`);
        per-sample statistics (`SparseGroupNorm`) are taken per batch index.

    Rows built by `voxelize` and `downsample` are in increasing `(b, i, j, k)` order, which
    keeps the gathers of a convolution close to sequential; no function relies on it.
    """

    coords: Int[Array, "n 4"]
    feats: Float[Array, "n c"]
    valid: Bool[Array, " n"]
    stride: int = eqx.field(static=True, default=1)
    batch_size: int = eqx.field(static=True, default=1)

    @property
    def capacity(self) -> int:
        return self.coords.shape[0]

    def replace_feats(self, feats: Float[Array, "n d"]) -> SparseTensor:
        """The same voxels with new features (padding rows zeroed)."""
        return SparseTensor(self.coords, jnp.where(self.valid[:, None], feats, 0.0).astype(feats.dtype),
                            self.valid, self.stride, self.batch_size)


class Voxelized(NamedTuple):
    """What `voxelize` returns.

    Attributes:
      tensor: the voxels, mean features, capacity `capacity`.
      point_voxel: `(n_points,)` int32, the row of each point's voxel; -1 for invalid points
        (and for points whose voxel did not fit, see `overflowed`).
      count: `(capacity,)` int32, points per voxel.
      overflowed: bool scalar, more occupied voxels than `capacity`.
    """

    tensor: SparseTensor
    point_voxel: Int[Array, " n"]
    count: Int[Array, " m"]
    overflowed: Bool[Array, ""]


def voxelize(points: Float[ArrayLike, "n 3"], features: Float[ArrayLike, "n c"], batch_index: Int[ArrayLike, " n"] | int,
             voxel_m: float, *, valid: Bool[ArrayLike, " n"] | None = None, capacity: int | None = None,
             batch_size: int = 1) -> Voxelized:
    """Bin points into voxels of edge `voxel_m` and average their features per voxel.

    Args:
      points: `(n, 3)` float32 metres in a local frame (grid index `floor(xyz / voxel_m)`
        must lie in the packable range `keys.COORD_MIN..COORD_MAX`).
      features: `(n, c)` per-point features.
      batch_index: `(n,)` int, the sample each point belongs to (0 for a single sample).
      voxel_m: voxel edge [m] (static).
      valid: `(n,)` bool, the points to use (default all).
      capacity: voxel rows (static; default `n`, which always fits).
      batch_size: number of samples (static; `batch_index < batch_size`).

    Raises:
      ValueError: `voxel_m <= 0`, shapes that disagree, or a grid index outside the
        packable range (named).
    """
    points, features = jnp.asarray(points, jnp.float32), jnp.asarray(features)
    n = points.shape[0]
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"voxelize: points must have shape (n, 3), got {points.shape}")
    if features.ndim != 2 or features.shape[0] != n:
        raise ValueError(f"voxelize: features must have shape ({n}, c), got {features.shape}")
    if not voxel_m > 0:
        raise ValueError(f"voxelize: voxel_m must be > 0, got {voxel_m}")
    batch_index = jnp.broadcast_to(jnp.asarray(batch_index, jnp.int32), (n,))
    valid = jnp.ones((n,), bool) if valid is None else jnp.asarray(valid, bool)
    capacity = n if capacity is None else int(capacity)
    grid = jnp.floor(points / jnp.float32(voxel_m))
    limit = jnp.float32(2 ** 20)                      # keeps the int cast defined; check_range names the range
    coords = jnp.concatenate([batch_index[:, None], jnp.clip(grid, -limit, limit).astype(jnp.int32)], axis=1)
    coords = K.check_range(coords, valid, "voxelize")
    return _voxelize(coords, features, valid, capacity=capacity, batch_size=batch_size)


@eqx.filter_jit
def _voxelize(coords, features, valid, *, capacity, batch_size):
    point_keys = K.pack(coords, valid)
    u = K.unique(point_keys, capacity=capacity)
    voxel_valid = jnp.arange(capacity) < u.count
    table = K.SortedKeys(u.keys.hi, u.keys.lo, jnp.arange(capacity, dtype=jnp.int32))
    point_voxel = K.lookup(table, point_keys, missing=-1)
    row = jnp.where(point_voxel >= 0, point_voxel, capacity)
    count = jax.ops.segment_sum(jnp.ones_like(row), row, num_segments=capacity + 1)[:-1]
    total = jax.ops.segment_sum(features, row, num_segments=capacity + 1)[:-1]
    mean = total / jnp.maximum(count, 1)[:, None].astype(total.dtype)
    voxel_coords = jnp.where(voxel_valid[:, None], K.unpack(u.keys), 0)
    tensor = SparseTensor(voxel_coords, jnp.where(voxel_valid[:, None], mean, 0.0), voxel_valid,
                          1, batch_size)
    return Voxelized(tensor, point_voxel, count.astype(jnp.int32), u.overflowed)


def devoxelize(feats: Float[Array, "m c"], point_voxel: Int[Array, " n"]) -> Float[Array, "n c"]:
    """Each point's voxel features `(n, c)`; 0 for points with `point_voxel == -1`."""
    safe = jnp.clip(point_voxel, 0, feats.shape[0] - 1)
    return jnp.where((point_voxel >= 0)[:, None], feats[safe], 0.0).astype(feats.dtype)
