"""Sparse 3D convolution in plain JAX: voxel sets, kernel maps, convolutions, equinox layers.

MinkowskiEngine-style sparse convolution (Choy et al. 2019) for networks on point clouds,
with no CUDA extension: every function is jit-able, differentiable and vmap-able, on CPU or
GPU alike.

- `SparseTensor`, `voxelize`, `devoxelize`: occupied voxels with features, padded to a
  static capacity with a `valid` mask; points to voxels (mean features) and back.
- `submanifold_map`, `downsample`, `strided_map`, `KernelMap.transpose`: the (input row,
  output row, offset) pairs of a convolution, found by sorting packed coordinate keys and a
  binary search (`keys`), grouped by offset in blocks; `inner_table` reads a smaller
  kernel's table off a larger one's.
- `sparse_conv`: gather -> matmul -> scatter-add over a map; only neighbours that exist cost
  multiply-adds. `table_conv`: the same over a `NeighbourTable` (no compaction, no scatter).
- `plan_pyramid`, `build_pyramid`: every map of a U-Net, built once per forward pass.
- `SparseConv3d`, `SparseBatchNorm`, `SparseGroupNorm`, `SparseResBlock`, `SparseLinear`:
  equinox layers (the batch norm's running statistics in an `eqx.nn.State`).

```python
>>> import equinox as eqx, jax, jax.numpy as jnp
>>> from gfjax.nn import sparse
>>> xyz = jax.random.uniform(jax.random.key(0), (500, 3), maxval=8.0)     # metres
>>> vox = sparse.voxelize(xyz, xyz, jnp.zeros(500, jnp.int32), voxel_m=1.0)
>>> x = vox.tensor                                                         # <= 512 voxels, 3 features
>>> kmap = sparse.submanifold_map(x.coords, x.valid, kernel_size=3)
>>> block, state = eqx.nn.make_with_state(sparse.SparseResBlock)(3, 16, key=jax.random.key(1))
>>> y, state = eqx.filter_jit(block)(x, kmap, state)                      # training: batch statistics
>>> y, _ = eqx.filter_jit(eqx.nn.inference_mode(block))(x, kmap, state)  # inference: running ones
>>> y.feats.shape
(500, 16)
>>> per_point = sparse.devoxelize(y.feats, vox.point_voxel)                # back to the 500 points
>>> per_point.shape
(500, 16)

```
"""
from gfjax.nn.sparse.conv import sparse_conv, table_conv
from gfjax.nn.sparse.keys import BATCH_MAX, COORD_MAX, COORD_MIN
from gfjax.nn.sparse.layers import SparseBatchNorm, SparseConv3d, SparseGroupNorm, SparseLinear, SparseResBlock, relu
from gfjax.nn.sparse.maps import (
                                    KernelMap,
                                    NeighbourTable,
                                    downsample,
                                    inner_table,
                                    kernel_offsets,
                                    neighbour_table,
                                    pairs_from_table,
                                    pairs_per_offset,
                                    plan_blocks,
                                    strided_map,
                                    submanifold_map,
)
from gfjax.nn.sparse.pyramid import Pyramid, PyramidPlan, build_pyramid, plan_pyramid, standard_plan
from gfjax.nn.sparse.tensor import SparseTensor, Voxelized, devoxelize, voxelize

__all__ = [
    "BATCH_MAX", "COORD_MAX", "COORD_MIN",
    "KernelMap", "NeighbourTable", "Pyramid", "PyramidPlan", "SparseBatchNorm", "SparseConv3d", "SparseGroupNorm", "SparseLinear", "SparseResBlock",
    "SparseTensor", "Voxelized",
    "build_pyramid", "devoxelize", "downsample", "inner_table", "kernel_offsets", "neighbour_table", "pairs_from_table",
    "pairs_per_offset", "plan_blocks", "plan_pyramid", "relu", "standard_plan", "sparse_conv", "strided_map", "submanifold_map",
    "table_conv", "voxelize",
]
