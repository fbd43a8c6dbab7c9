"""Equinox layers over `SparseTensor`s: convolution, batch and group norms, residual block.

Every layer takes the kernel map it runs on as an argument (built once per forward pass by
`Pyramid`), so layers hold only parameters; the batch norm's running statistics live in an
`eqx.nn.State` that the caller threads through (`eqx.nn.make_with_state`).

Initialisation (He et al. 2015, "Delving deep into rectifiers"; what MinkowskiEngine and
PyTorch's `kaiming_normal_(mode="fan_out")` use for convolutions before ReLU): weights
`N(0, 2 / fan)` with `fan = kernel_volume * c_out` (fan-out; the transposed convolution
uses the same rule on its own weight), biases 0. Norms start as the identity map (scale 1,
shift 0), except the second norm of a residual block, whose scale starts at 0, so a new
residual block is the identity (Goyal et al. 2017, "zero-init residual").
"""
from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from gfjax.nn.sparse.conv import sparse_conv, table_conv
from gfjax.nn.sparse.maps import KernelMap, NeighbourTable
from gfjax.nn.sparse.tensor import SparseTensor


def _he_normal(key: PRNGKeyArray | None, shape: tuple[int, ...], std: float) -> Array:
    """Weights drawn from N(0, std²) (He et al. 2015); zeros for `key=None`: a layer made only
    for its shapes, whose weights are read next (`gfjax.sparsegf.checkpoint.load`: drawing
    them under `eval_shape` costs 0.13 s of tracing)."""
    if key is None:
        return jnp.zeros(shape, jnp.float32)
    return std * jax.random.normal(key, shape, jnp.float32)


class SparseConv3d(eqx.Module):
    """Sparse 3D convolution `(k**3, c_in, c_out)`.

    `stride=1` is submanifold (give it a `submanifold_map` of the same kernel size, or the
    `NeighbourTable` of one);
    `stride=2, kernel_size=2` goes to the coarser level (`strided_map`); with
    `transposed=True` it comes back (the strided map's `.transpose()`). The layer checks that
    the map's kernel volume matches its own; which voxel sets the map joins is the map's
    business.
    """

    weight: Float[Array, "k c_in c_out"]
    bias: Float[Array, " c_out"] | None
    kernel_size: int = eqx.field(static=True)
    stride: int = eqx.field(static=True)
    transposed: bool = eqx.field(static=True)
    chunk_blocks: int | None = eqx.field(static=True)

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, *, stride: int = 1,
                 transposed: bool = False, use_bias: bool = False, chunk_blocks: int | None = None,
                 key: PRNGKeyArray | None):
        volume = kernel_size ** 3
        std = math.sqrt(2.0 / (volume * out_channels))
        self.weight = _he_normal(key, (volume, in_channels, out_channels), std)
        self.bias = jnp.zeros((out_channels,), jnp.float32) if use_bias else None
        self.kernel_size, self.stride, self.transposed = kernel_size, stride, transposed
        self.chunk_blocks = chunk_blocks

    def __call__(self, x: SparseTensor, kmap: KernelMap | NeighbourTable) -> SparseTensor:
        if kmap.kernel_volume != self.weight.shape[0]:
            raise ValueError(f"SparseConv3d: kernel {self.kernel_size} needs a map of {self.weight.shape[0]} "
                             f"offsets, got {kmap.kernel_volume}")
        if isinstance(kmap, NeighbourTable):
            y = table_conv(x.feats, self.weight, kmap)
        else:
            y = sparse_conv(x.feats, self.weight, kmap, chunk_blocks=self.chunk_blocks)
        if self.bias is not None:
            y = y + self.bias[None, :]
        if self.stride == 1:
            out_stride = x.stride
        else:
            out_stride = x.stride // self.stride if self.transposed else x.stride * self.stride
        y = jnp.where(kmap.out_valid[:, None], y, 0.0)            # a bias must not reach padding rows
        return SparseTensor(kmap.out_coords, y, kmap.out_valid, max(out_stride, 1), x.batch_size)


class SparseGroupNorm(eqx.Module):
    """Group normalisation (Wu & He 2018) over the valid rows of each sample.

    Statistics are per batch index and per group of channels, over every valid voxel of
    that sample, so a sample's output does not depend on what it is batched with (unlike
    batch norm, whose statistics mix samples and need running averages for inference).
    """

    scale: Float[Array, " c"]
    shift: Float[Array, " c"]
    groups: int = eqx.field(static=True)
    eps: float = eqx.field(static=True)

    def __init__(self, channels: int, *, groups: int = 8, eps: float = 1e-5, zero_scale: bool = False):
        groups = math.gcd(groups, channels)
        self.scale = jnp.full((channels,), 0.0 if zero_scale else 1.0, jnp.float32)
        self.shift = jnp.zeros((channels,), jnp.float32)
        self.groups, self.eps = groups, eps

    def __call__(self, x: SparseTensor, weight: Float[Array, " n"] | None = None) -> SparseTensor:
        """Normalised `x`; `weight` `(n,)` (optional, >= 0) counts each valid row that many
        times in the statistics (e.g. the points a voxel holds), so per-voxel statistics equal
        per-point ones."""
        f = x.feats
        n, c = f.shape
        seg = jnp.where(x.valid, x.coords[:, 0], x.batch_size)
        g = f.reshape(n, self.groups, c // self.groups)
        w = x.valid.astype(f.dtype) if weight is None else jnp.where(x.valid, weight, 0.0).astype(f.dtype)
        w = w[:, None]
        count = jax.ops.segment_sum(w[:, 0], seg, num_segments=x.batch_size + 1) * (c // self.groups)
        s1 = jax.ops.segment_sum(jnp.sum(g, axis=2) * w, seg, num_segments=x.batch_size + 1)
        s2 = jax.ops.segment_sum(jnp.sum(g * g, axis=2) * w, seg, num_segments=x.batch_size + 1)
        denom = jnp.maximum(count, 1.0)[:, None]
        mean = s1 / denom
        var = jnp.maximum(s2 / denom - mean * mean, 0.0)
        inv = jax.lax.rsqrt(var + self.eps)                                   # (batch + 1, groups)
        y = (g - mean[seg][:, :, None]) * inv[seg][:, :, None]
        return x.replace_feats(y.reshape(n, c) * self.scale[None, :] + self.shift[None, :])


class SparseBatchNorm(eqx.Module):
    """Batch normalisation (Ioffe & Szegedy 2015) over the valid rows of a sparse tensor, as
    MinkowskiEngine's (a `torch.nn.BatchNorm1d` over the voxels of the whole batch).

    In training (`inference=False`) a call normalises with the mean and variance of its own
    valid rows, every sample of the batch together, and moves the running averages in `state`
    towards them by `momentum` (the variance unbiased, as PyTorch's). With `inference=True`
    (`eqx.nn.inference_mode`) it uses the running averages: an affine map per channel, so a
    sample's output depends neither on its batch nor on other samples, and heights keep their
    absolute scale (a group or instance norm would re-centre every patch on its own mean).
    """

    scale: Float[Array, " c"]
    shift: Float[Array, " c"]
    index: eqx.nn.StateIndex
    inference: bool
    momentum: float = eqx.field(static=True)
    eps: float = eqx.field(static=True)

    def __init__(self, channels: int, *, momentum: float = 0.1, eps: float = 1e-5, zero_scale: bool = False,
                 inference: bool = False):
        self.scale = jnp.full((channels,), 0.0 if zero_scale else 1.0, jnp.float32)
        self.shift = jnp.zeros((channels,), jnp.float32)
        self.index = eqx.nn.StateIndex((jnp.zeros((channels,), jnp.float32), jnp.ones((channels,), jnp.float32)))
        self.inference, self.momentum, self.eps = inference, momentum, eps

    def __call__(self, x: SparseTensor, state: eqx.nn.State,
                 weight: Float[Array, " n"] | None = None) -> tuple[SparseTensor, eqx.nn.State]:
        """Normalised `x` and the new state; `weight` `(n,)` (optional, >= 0) counts each valid
        row that many times in the batch statistics (e.g. the points a voxel holds)."""
        f = x.feats
        if self.inference:
            mean, var = state.get(self.index)
        else:
            w = (x.valid.astype(f.dtype) if weight is None else jnp.where(x.valid, weight, 0.0).astype(f.dtype))
            n = jnp.sum(w)
            mean = jnp.sum(f * w[:, None], axis=0) / jnp.maximum(n, 1.0)
            var = jnp.sum(jnp.square(f - mean[None, :]) * w[:, None], axis=0) / jnp.maximum(n, 1.0)
            running_mean, running_var = state.get(self.index)
            unbiased = var * n / jnp.maximum(n - 1.0, 1.0)
            m = self.momentum
            new = ((1 - m) * running_mean + m * mean, (1 - m) * running_var + m * unbiased)
            state = state.set(self.index, jax.lax.stop_gradient(new))
        y = (f - mean[None, :]) * jax.lax.rsqrt(var + self.eps)[None, :]
        return x.replace_feats(y * self.scale[None, :] + self.shift[None, :]), state


def relu(x: SparseTensor) -> SparseTensor:
    return x.replace_feats(jax.nn.relu(x.feats))


class SparseLinear(eqx.Module):
    """A per-voxel (or per-point) linear map, `(c_in, c_out)`: a 1x1x1 convolution."""

    weight: Float[Array, "c_in c_out"]
    bias: Float[Array, " c_out"] | None

    def __init__(self, in_channels: int, out_channels: int, *, use_bias: bool = True, key: PRNGKeyArray | None):
        std = math.sqrt(2.0 / out_channels)
        self.weight = _he_normal(key, (in_channels, out_channels), std)
        self.bias = jnp.zeros((out_channels,), jnp.float32) if use_bias else None

    def __call__(self, feats: Float[Array, "n c_in"]) -> Float[Array, "n c_out"]:
        y = feats @ self.weight
        return y if self.bias is None else y + self.bias[None, :]


class SparseResBlock(eqx.Module):
    """Basic residual block (He et al. 2016; MinkowskiEngine's `BasicBlock`) on one voxel set:
    conv3 -> batch norm -> ReLU -> conv3 -> batch norm, plus the input (through a linear map
    when the channel count changes), then ReLU. Both convolutions share the level's
    submanifold map; the norms' running statistics are in `state`."""

    conv1: SparseConv3d
    norm1: SparseBatchNorm
    conv2: SparseConv3d
    norm2: SparseBatchNorm
    shortcut: SparseLinear | None

    def __init__(self, in_channels: int, out_channels: int, *, kernel_size: int = 3,
                 chunk_blocks: int | None = None, key: PRNGKeyArray | None):
        k1, k2, k3 = (None, None, None) if key is None else jax.random.split(key, 3)
        self.conv1 = SparseConv3d(in_channels, out_channels, kernel_size, chunk_blocks=chunk_blocks, key=k1)
        self.norm1 = SparseBatchNorm(out_channels)
        self.conv2 = SparseConv3d(out_channels, out_channels, kernel_size, chunk_blocks=chunk_blocks, key=k2)
        self.norm2 = SparseBatchNorm(out_channels, zero_scale=True)
        self.shortcut = (None if in_channels == out_channels
                         else SparseLinear(in_channels, out_channels, use_bias=False, key=k3))

    def __call__(self, x: SparseTensor, kmap: KernelMap, state: eqx.nn.State) -> tuple[SparseTensor, eqx.nn.State]:
        h, state = self.norm1(self.conv1(x, kmap), state)
        h, state = self.norm2(self.conv2(relu(h), kmap), state)
        skip = x.feats if self.shortcut is None else self.shortcut(x.feats)
        return relu(h.replace_feats(h.feats + skip)), state
