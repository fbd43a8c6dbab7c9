"""SparseGF's hybrid sparse voxel-point network (Qin et al. 2026, Sec. 2.2.1, Fig. 3).

    voxels (0.5 m) --stem k5--> 4 x [k2 s2 conv + residual blocks]            (encoder)
                  <-- 4 x [k2 s2 transposed conv + skip concat + residual blocks]  (decoder)
    central points <- projected encoder features of the 4 down blocks --4 LBR--> concat --LBR-->
                   <- projected decoder output -------------------------------------> concat
                   --> classification head (ground / non-ground), HAG head (6 bins)

The backbone is MinkUNet (Choy et al. 2019): stem convolution of kernel 5, then per level a
kernel-2 stride-2 convolution and `layers[l]` residual blocks; the decoder mirrors it with
transposed convolutions whose output is concatenated with the encoder's features of the
same level (U-Net skips). `paper` has MinkUNet34C's widths and depths, as the paper uses
(37.9 M parameters); `tiny` keeps the structure with small widths and 1 block per level,
so that it trains on 2 CPU cores.

Points take the features of the voxel that holds them at each level ("projection": nearest,
no interpolation). The point-wise refinement module (Sec. 2.2.1) passes each of the four
encoder scales through an LBR (Linear, norm, ReLU), concatenates them and fuses them with a
fifth LBR; the result is concatenated with the decoder's output and fed to the two linear
heads. Norms are group norms (per patch, over valid voxels or central points) instead of
the paper's batch norms: a patch's output then does not depend on its batch, and inference
needs no running statistics.

Pure JAX + equinox; one patch per call (batch with `jax.vmap`).
"""
from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from gfjax.nn import sparse
from gfjax.nn.sparse import keys as K
from gfjax.sparsegf.hag import N_HAG_BINS

N_FEATURES = 4          # per-point input features, see `gfjax.sparsegf.pipeline.point_features`


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Static shape of the network.

    Attributes:
      stem: channels of the stem convolution (MinkUNet's INIT_DIM).
      planes: output channels of the 4 encoder levels then the 4 decoder levels.
      layers: residual blocks after each of those 8 (strided or transposed) convolutions.
      refine: channels of each refinement LBR (0: no refinement module, the ablation).
      groups: channel groups of the group norms.
      in_features: per-point input features.
    """

    stem: int = 32
    planes: tuple[int, ...] = (32, 64, 128, 256, 256, 128, 96, 96)
    layers: tuple[int, ...] = (2, 3, 4, 6, 2, 2, 2, 2)
    refine: int = 32
    groups: int = 8
    in_features: int = N_FEATURES

    def __post_init__(self):
        if len(self.planes) != 8 or len(self.layers) != 8:
            raise ValueError(f"NetConfig: planes and layers need 8 entries each, got {self.planes}, {self.layers}")
        if self.stem < 1 or min(self.planes) < 1 or min(self.layers) < 0 or self.refine < 0:
            raise ValueError("NetConfig: channel counts must be >= 1 and block counts >= 0")

    @property
    def depth(self) -> int:
        return 4


NET_PRESETS: dict[str, NetConfig] = {
    "tiny": NetConfig(stem=16, planes=(16, 32, 48, 64, 48, 32, 24, 24), layers=(1, 1, 1, 1, 1, 1, 1, 1),
                      refine=16, groups=4),
    "paper": NetConfig(),
}


class _LBR(eqx.Module):
    """Linear -> group norm over the masked rows -> ReLU (the paper's LBR)."""

    linear: sparse.SparseLinear
    norm: sparse.SparseGroupNorm

    def __init__(self, c_in: int, c_out: int, groups: int, *, key: PRNGKeyArray):
        self.linear = sparse.SparseLinear(c_in, c_out, use_bias=False, key=key)
        self.norm = sparse.SparseGroupNorm(c_out, groups=groups)

    def __call__(self, feats, mask):
        t = sparse.SparseTensor(jnp.zeros((feats.shape[0], 4), jnp.int32), self.linear(feats), mask)
        return jax.nn.relu(self.norm(t).feats)


class Outputs(eqx.Module):
    """Per point of the patch: `cls` `(n, 2)` logits (index 1 = ground) and `hag` `(n, 6)`
    logits; rows outside the central mask are 0."""

    cls: Float[Array, "n 2"]
    hag: Float[Array, "n c"]


class SparseGFNet(eqx.Module):
    """The network; `__call__` maps one voxelized patch to per-point logits."""

    stem: sparse.SparseConv3d
    stem_norm: sparse.SparseGroupNorm
    down: tuple[sparse.SparseConv3d, ...]
    down_norm: tuple[sparse.SparseGroupNorm, ...]
    enc: tuple[tuple[sparse.SparseResBlock, ...], ...]
    up: tuple[sparse.SparseConv3d, ...]
    up_norm: tuple[sparse.SparseGroupNorm, ...]
    dec: tuple[tuple[sparse.SparseResBlock, ...], ...]
    refine: tuple[_LBR, ...]
    head_cls: sparse.SparseLinear
    head_hag: sparse.SparseLinear
    config: NetConfig = eqx.field(static=True)

    def __init__(self, config: NetConfig, *, key: PRNGKeyArray):
        c = config
        keys = iter(jax.random.split(key, 64 + 4 * sum(c.layers)))
        g = c.groups
        self.config = c
        self.stem = sparse.SparseConv3d(c.in_features, c.stem, 5, key=next(keys))
        self.stem_norm = sparse.SparseGroupNorm(c.stem, groups=g)
        down, down_norm, enc, widths = [], [], [], [c.stem]
        width = c.stem
        for level in range(4):
            down.append(sparse.SparseConv3d(width, width, 2, stride=2, key=next(keys)))
            down_norm.append(sparse.SparseGroupNorm(width, groups=g))
            blocks = []
            for _ in range(c.layers[level]):
                blocks.append(sparse.SparseResBlock(width, c.planes[level], groups=g, key=next(keys)))
                width = c.planes[level]
            enc.append(tuple(blocks))
            widths.append(width)
        up, up_norm, dec = [], [], []
        for step in range(4):
            level = 3 - step                                   # going up from level+1 to level
            planes = c.planes[4 + step]
            up.append(sparse.SparseConv3d(width, planes, 2, stride=2, transposed=True, key=next(keys)))
            up_norm.append(sparse.SparseGroupNorm(planes, groups=g))
            width = planes + widths[level]
            blocks = []
            for _ in range(c.layers[4 + step]):
                blocks.append(sparse.SparseResBlock(width, planes, groups=g, key=next(keys)))
                width = planes
            dec.append(tuple(blocks))
        self.down, self.down_norm, self.enc = tuple(down), tuple(down_norm), tuple(enc)
        self.up, self.up_norm, self.dec = tuple(up), tuple(up_norm), tuple(dec)
        if c.refine:
            self.refine = tuple(_LBR(widths[1 + l], c.refine, g, key=next(keys)) for l in range(4)) + (
                _LBR(4 * c.refine, c.refine, g, key=next(keys)),)
            head_in = width + c.refine
        else:
            self.refine = ()
            head_in = width
        self.head_cls = sparse.SparseLinear(head_in, 2, key=next(keys))
        self.head_hag = sparse.SparseLinear(head_in, N_HAG_BINS, key=next(keys))

    def __call__(self, x: sparse.SparseTensor, pyramid: sparse.Pyramid, point_voxel: Int[Array, " n"],
                 central: Bool[Array, " n"]) -> Outputs:
        """Logits of the central points of one patch.

        Args:
          x: level-0 voxels of the compressed patch, features `(m, in_features)`.
          pyramid: `build_pyramid(x.coords, x.valid, plan)`, depth 4.
          point_voxel: `(n,)` int32, each point's row in `x` (-1: padding).
          central: `(n,)` bool, the points to classify.
        """
        central = central & (point_voxel >= 0)
        h = sparse.relu(self.stem_norm(self.stem(x, pyramid.stem)))
        skips = [h]
        for level in range(4):
            h = sparse.relu(self.down_norm[level](self.down[level](h, pyramid.down[level])))
            for block in self.enc[level]:
                h = block(h, pyramid.submanifold[level + 1])
            skips.append(h)
        for step in range(4):
            level = 3 - step
            h = sparse.relu(self.up_norm[step](self.up[step](h, pyramid.up(level))))
            h = h.replace_feats(jnp.concatenate([h.feats, skips[level].feats], axis=1))
            for block in self.dec[step]:
                h = block(h, pyramid.submanifold[level])
        point_coords = x.coords[jnp.maximum(point_voxel, 0)]
        features = [sparse.devoxelize(h.feats, jnp.where(central, point_voxel, -1))]
        if self.refine:
            scales = []
            for level in range(4):
                row = _locate(point_coords, central, pyramid.coords[level + 1], pyramid.valid[level + 1], 2 ** (level + 1))
                scales.append(self.refine[level](sparse.devoxelize(skips[level + 1].feats, row), central))
            features.append(self.refine[4](jnp.concatenate(scales, axis=1), central))
        f = jnp.concatenate(features, axis=1)
        mask = central[:, None]
        return Outputs(jnp.where(mask, self.head_cls(f), 0.0), jnp.where(mask, self.head_hag(f), 0.0))


def _locate(coords0: Int[Array, "n 4"], valid: Bool[Array, " n"], level_coords: Int[Array, "m 4"],
            level_valid: Bool[Array, " m"], stride: int) -> Int[Array, " n"]:
    """Row of the level-`stride` voxel holding each level-0 voxel, -1 where none."""
    query = jnp.concatenate([coords0[:, :1], jnp.floor_divide(coords0[:, 1:], stride)], axis=1)
    table = K.sort_keys(K.pack(level_coords, level_valid))
    return K.lookup(table, K.pack(query, valid), missing=-1)


def count_parameters(config: NetConfig) -> int:
    """Trainable values of a network of this shape (no weights are allocated)."""
    shapes = eqx.filter_eval_shape(SparseGFNet, config, key=jax.random.key(0))
    return sum(math.prod(a.shape) for a in jax.tree_util.tree_leaves(shapes) if hasattr(a, "shape"))
