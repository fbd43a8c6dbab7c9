"""SparseGF's hybrid sparse voxel-point network (Qin et al. 2026, Sec. 2.2.1, Fig. 3).

    voxels (0.5 m) --stem k5--> 4 x [k2 s2 conv + residual blocks]            (encoder)
                  <-- 4 x [k2 s2 transposed conv + skip concat + residual blocks]  (decoder)
    central points <- projected encoder features of the 4 down blocks --4 LBR--> concat --LBR-->
                   <- projected decoder output -------------------------------------> concat
                   <- the point's own features less its voxel's --LR-------------------> concat
                   --> classification head (ground / non-ground), HAG head (6 bins)

The backbone is MinkUNet (Choy et al. 2019): stem convolution of kernel 5, then per level a
kernel-2 stride-2 convolution and `layers[l]` residual blocks; the decoder mirrors it with
transposed convolutions whose output is concatenated with the encoder's features of the
same level (U-Net skips). `paper` has MinkUNet34C's widths and depths, as the paper uses
(37.9 M parameters); `tiny` keeps the structure with small widths and 1 block per level,
so that it trains on 2 CPU cores.

Central points take the features of the voxel that holds them at each level ("projection":
nearest, as MinkowskiEngine's slicing, no interpolation). The point-wise refinement module
(Sec. 2.2.1) passes each of the four encoder scales through an LBR (Linear, norm, ReLU),
concatenates them and fuses them with a fifth LBR; as every point of a level-0 voxel gets the
same projected features, this part runs once per voxel that holds central points. Its result
is concatenated with the decoder's output, gathered to the central points and concatenated
with what is the point's own, the point branch of a voxel-point network: its input features
less its voxel's mean, through a Linear and a ReLU. The two linear heads read that, so two
points of one 0.5 m voxel (a ground return under a shrub) can get different labels. Norms are batch norms, as in the paper and MinkUNet (over the valid voxels of a batch;
in the refinement module over central points, each voxel weighted by the central points it
holds, so the statistics are the per-point ones), with their statistics measured on the
training data before the first step and then frozen (`train.calibrate`): training and
inference compute the same function, and a patch's output does not depend on the patches it
is packed with. (Tried and measured first: a per-patch group norm re-centres every patch on
its own mean and blurs the absolute heights that separate a roof from the ground; batch
statistics in every step normalise a dense forest pack by its own statistics in training and
by the average of all packs in inference.)

Pure JAX + equinox. A call takes one sparse tensor, which may hold several patches under
different batch indices (`gfjax.sparsegf.pipeline.pack`).
"""
from __future__ import annotations

import dataclasses
import itertools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from gfjax.nn import sparse
from gfjax.sparsegf.config import Config
from gfjax.sparsegf.features import n_features
from gfjax.sparsegf.hag import N_HAG_BINS


@dataclasses.dataclass(frozen=True)
class NetConfig:
    """Static shape of the network.

    Attributes:
      stem: channels of the stem convolution (MinkUNet's INIT_DIM).
      planes: output channels of the 4 encoder levels then the 4 decoder levels.
      layers: residual blocks after each of those 8 (strided or transposed) convolutions.
      refine: channels of each refinement LBR (0: no refinement module, the ablation).
      point: channels of the point branch (a point's own features).
      in_features: per-point input features (`features.n_features`; default: those of the
        default feature set, `Config.features`).
    """

    stem: int = 32
    planes: tuple[int, ...] = (32, 64, 128, 256, 256, 128, 96, 96)
    layers: tuple[int, ...] = (2, 3, 4, 6, 2, 2, 2, 2)
    refine: int = 32
    point: int = 32
    in_features: int = n_features(Config.features)

    def __post_init__(self):
        if len(self.planes) != 8 or len(self.layers) != 8:
            raise ValueError(f"NetConfig: planes and layers need 8 entries each, got {self.planes}, {self.layers}")
        if self.stem < 1 or min(self.planes) < 1 or min(self.layers) < 0 or self.refine < 0 or self.point < 1:
            raise ValueError("NetConfig: channel counts must be >= 1 and block counts >= 0")

    @property
    def depth(self) -> int:
        return 4


NET_PRESETS: dict[str, NetConfig] = {
    "tiny": NetConfig(stem=16, planes=(16, 32, 48, 64, 48, 32, 24, 24), layers=(1, 1, 1, 1, 1, 1, 1, 1),
                      refine=16, point=16),
    "paper": NetConfig(),
}


class _LBR(eqx.Module):
    """Linear -> batch norm over the central points -> ReLU (the paper's LBR)."""

    linear: sparse.SparseLinear
    norm: sparse.SparseBatchNorm

    def __init__(self, c_in: int, c_out: int, *, key: PRNGKeyArray | None):
        self.linear = sparse.SparseLinear(c_in, c_out, use_bias=False, key=key)
        self.norm = sparse.SparseBatchNorm(c_out)

    def __call__(self, x: sparse.SparseTensor, feats, weight, state):
        y, state = self.norm(x.replace_feats(self.linear(feats)), state, weight)
        return jax.nn.relu(y.feats), state


class Outputs(eqx.Module):
    """Per central point row: `cls` `(p, 2)` logits (index 1 = ground) and `hag` `(p, 6)`
    logits; padding rows are 0."""

    cls: Float[Array, "p 2"]
    hag: Float[Array, "p c"]


class SparseGFNet(eqx.Module):
    """The network; `__call__` maps one voxelized patch to per-point logits."""

    stem: sparse.SparseConv3d
    stem_norm: sparse.SparseBatchNorm
    down: tuple[sparse.SparseConv3d, ...]
    down_norm: tuple[sparse.SparseBatchNorm, ...]
    enc: tuple[tuple[sparse.SparseResBlock, ...], ...]
    up: tuple[sparse.SparseConv3d, ...]
    up_norm: tuple[sparse.SparseBatchNorm, ...]
    dec: tuple[tuple[sparse.SparseResBlock, ...], ...]
    refine: tuple[_LBR, ...]
    point: sparse.SparseLinear
    head_cls: sparse.SparseLinear
    head_hag: sparse.SparseLinear
    config: NetConfig = eqx.field(static=True)

    def __init__(self, config: NetConfig, *, key: PRNGKeyArray | None):
        c = config
        keys = itertools.repeat(None) if key is None else iter(jax.random.split(key, 64 + 4 * sum(c.layers)))
        self.config = c
        self.stem = sparse.SparseConv3d(c.in_features, c.stem, 5, key=next(keys))
        self.stem_norm = sparse.SparseBatchNorm(c.stem)
        down, down_norm, enc, widths = [], [], [], [c.stem]
        width = c.stem
        for level in range(4):
            down.append(sparse.SparseConv3d(width, width, 2, stride=2, key=next(keys)))
            down_norm.append(sparse.SparseBatchNorm(width))
            blocks = []
            for _ in range(c.layers[level]):
                blocks.append(sparse.SparseResBlock(width, c.planes[level], key=next(keys)))
                width = c.planes[level]
            enc.append(tuple(blocks))
            widths.append(width)
        up, up_norm, dec = [], [], []
        for step in range(4):
            level = 3 - step                                   # going up from level+1 to level
            planes = c.planes[4 + step]
            up.append(sparse.SparseConv3d(width, planes, 2, stride=2, transposed=True, key=next(keys)))
            up_norm.append(sparse.SparseBatchNorm(planes))
            width = planes + widths[level]
            blocks = []
            for _ in range(c.layers[4 + step]):
                blocks.append(sparse.SparseResBlock(width, planes, key=next(keys)))
                width = planes
            dec.append(tuple(blocks))
        self.down, self.down_norm, self.enc = tuple(down), tuple(down_norm), tuple(enc)
        self.up, self.up_norm, self.dec = tuple(up), tuple(up_norm), tuple(dec)
        if c.refine:
            self.refine = tuple(_LBR(widths[1 + k], c.refine, key=next(keys)) for k in range(4)) + (
                _LBR(4 * c.refine, c.refine, key=next(keys)),)
            head_in = width + c.refine
        else:
            self.refine = ()
            head_in = width
        self.point = sparse.SparseLinear(c.in_features, c.point, key=next(keys))
        head_in += c.point
        self.head_cls = sparse.SparseLinear(head_in, 2, key=next(keys))
        self.head_hag = sparse.SparseLinear(head_in, N_HAG_BINS, key=next(keys))

    def __call__(self, x: sparse.SparseTensor, pyramid: sparse.Pyramid, weight: Float[Array, " m"],
                 point_row: Int[Array, " p"], point_feats: Float[Array, "p f"], point_valid: Bool[Array, " p"],
                 state: eqx.nn.State) -> tuple[Outputs, eqx.nn.State]:
        """Logits of the central points and the new state.

        Args:
          x: level-0 voxels of one or more compressed patches (batch index = patch), features
            `(m, in_features)`.
          pyramid: `build_pyramid(x.coords, x.valid, plan)`, depth 4.
          weight: `(m,)` float, the central points each voxel holds (0: context only).
          point_row: `(p,)` int32, each central point's level-0 voxel (a row of `x`).
          point_feats: `(p, in_features)`, its input features less its voxel's.
          point_valid: `(p,)` bool, real rows (the others are padding).
          state: the batch norms' running statistics (`init`); updated in training, read in
            inference (`eqx.nn.inference_mode(net)`).
        """
        def norm_relu(layer, t, state):
            t, state = layer(t, state)
            return sparse.relu(t), state

        h, state = norm_relu(self.stem_norm, self.stem(x, pyramid.stem), state)
        skips = [h]
        for level in range(4):
            h, state = norm_relu(self.down_norm[level], self.down[level](h, pyramid.down[level]), state)
            for block in self.enc[level]:
                h, state = block(h, pyramid.submanifold[level + 1], state)
            skips.append(h)
        for step in range(4):
            level = 3 - step
            h, state = norm_relu(self.up_norm[step], self.up[step](h, pyramid.up(level)), state)
            h = h.replace_feats(jnp.concatenate([h.feats, skips[level].feats], axis=1))
            for block in self.dec[step]:
                h, state = block(h, pyramid.submanifold[level], state)
        central = x.valid & (weight > 0)
        points = sparse.SparseTensor(x.coords, jnp.zeros_like(x.feats[:, :1]), central, 1, x.batch_size)
        features = [h.feats]
        if self.refine:
            row = jnp.arange(x.capacity, dtype=jnp.int32)
            scales = []
            for level in range(4):
                row = pyramid.parent(level)[row]               # row at level + 1 of each level-0 voxel
                f, state = self.refine[level](points, skips[level + 1].feats[row], weight, state)
                scales.append(f)
            f, state = self.refine[4](points, jnp.concatenate(scales, axis=1), weight, state)
            features.append(f)
        own = jax.nn.relu(self.point(jnp.where(point_valid[:, None], point_feats, 0.0)))
        f = jnp.concatenate([jnp.concatenate(features, axis=1)[point_row], own], axis=1)
        mask = point_valid[:, None]
        return Outputs(jnp.where(mask, self.head_cls(f), 0.0), jnp.where(mask, self.head_hag(f), 0.0)), state


class Model(NamedTuple):
    """A SparseGF network and its state (the running statistics of its batch norms)."""

    net: SparseGFNet
    state: eqx.nn.State


def init(config: NetConfig, *, key: PRNGKeyArray | None) -> Model:
    """A new network of shape `config` with He-initialised weights and fresh statistics
    (`key=None`: zero weights, a network made for its shapes only)."""
    return Model(*eqx.nn.make_with_state(SparseGFNet)(config, key=key))


def count_parameters(config: NetConfig) -> int:
    """Trainable values of a network of this shape (no weights are allocated; the batch
    norms' running statistics are not counted)."""
    shapes = eqx.filter_eval_shape(SparseGFNet, config, key=jax.random.key(0))
    shapes = jax.tree_util.tree_map(lambda x: None if isinstance(x, eqx.nn.StateIndex) else x, shapes,
                                    is_leaf=lambda x: isinstance(x, eqx.nn.StateIndex))
    return sum(math.prod(a.shape) for a in jax.tree_util.tree_leaves(shapes) if hasattr(a, "shape"))
