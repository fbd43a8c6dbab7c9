"""Training SparseGF (Qin et al. 2026, Sec. 3.3): height-aware loss, Adam, cosine schedule.

One step takes a batch of voxelized patches (random rotation about z, the paper's
augmentation), runs the network under `jax.vmap`, and minimises the height-aware loss
(Eqs. 4-5) over the central points. Labels: ground = class 2, every other class non-ground
(noise included, as the paper relabels outliers); HAG bins from the labelled ground's TIN.
"""
from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from gfjax.sparsegf.config import Config
from gfjax.sparsegf.filter import patches
from gfjax.sparsegf.hag import hag_targets
from gfjax.sparsegf.loss import LAMBDA, height_aware_loss
from gfjax.sparsegf.model import SparseGFNet
from gfjax.sparsegf.pipeline import Batch, forward, stack

LR_START, LR_END = 1e-1, 1e-3     # cosine schedule bounds (Sec. 3.3)


class Labelled(NamedTuple):
    """A training cloud: `xyz_m` `(n, 3)` [m], `ground` `(n,)` bool, `hag_bin` `(n,)` int32."""

    xyz_m: np.ndarray
    ground: np.ndarray
    hag_bin: np.ndarray


def labelled(xyz_m: np.ndarray, classification: np.ndarray, *, ground_class: int = 2) -> Labelled:
    cls = np.where(np.asarray(classification) == ground_class, 2, 1)
    t = hag_targets(xyz_m, cls)
    return Labelled(np.asarray(xyz_m, np.float64), t.ground, t.bins)


def training_batches(data: list[Labelled], config: Config, *, batch_size: int, rng: np.random.Generator):
    """One epoch of batches: every patch of every cloud once, shuffled, randomly rotated."""
    items = []
    for d in data:
        angle = float(rng.uniform(0.0, 2 * np.pi))
        for p in patches(d.xyz_m, config, angle=angle, seed=int(rng.integers(1 << 30))):
            items.append((d, p))
    order = rng.permutation(len(items))
    for start in range(0, len(order), batch_size):
        group = [items[i] for i in order[start:start + batch_size]]
        batch = stack([p for _, p in group])
        b = batch.patch
        labels = np.zeros(b.index.shape, np.int32)
        bins = np.zeros(b.index.shape, np.int32)
        for row, (d, p) in enumerate(group):
            ok = b.index[row] >= 0
            labels[row, ok] = d.ground[b.index[row, ok]]
            bins[row, ok] = d.hag_bin[b.index[row, ok]]
        yield batch, labels, bins


def optimizer(steps: int) -> optax.GradientTransformation:
    schedule = optax.cosine_decay_schedule(LR_START, max(steps, 1), alpha=LR_END / LR_START)
    return optax.adam(schedule)


@eqx.filter_jit
def train_step(net: SparseGFNet, opt_state, batch: Batch, labels, bins, opt: optax.GradientTransformation,
               lam: float = LAMBDA):
    """One Adam step on a batch; returns `(net, opt_state, loss)` (loss: `HeightAwareLoss`)."""

    def loss_fn(net):
        b = batch.patch
        out = jax.vmap(lambda c, f, v, pv, ce: forward(net, c, f, v, pv, ce, batch.plan))(
            b.coords, b.feats, b.vvalid, b.point_voxel, b.central)
        mask = b.central & (b.point_voxel >= 0)
        loss = height_aware_loss(out.cls, out.hag, labels, bins, mask, lam=lam)
        return loss.total, loss

    (_, loss), grads = eqx.filter_value_and_grad(loss_fn, has_aux=True)(net)
    with jax.numpy_dtype_promotion("standard"):          # optax: float ** int32 step count
        updates, opt_state = opt.update(grads, opt_state, eqx.filter(net, eqx.is_array))
    return eqx.apply_updates(net, updates), opt_state, loss


def init(net: SparseGFNet, steps: int):
    opt = optimizer(steps)
    with jax.numpy_dtype_promotion("standard"):
        return opt, opt.init(eqx.filter(net, eqx.is_array))
