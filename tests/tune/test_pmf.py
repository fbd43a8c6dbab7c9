"""Relaxed PMF: hard mode equals the plain filter bit for bit; gradients of all three
parameters are correct and non-zero on a labelled crop; losses finite on one-class tiles."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax import metrics
from gfjax.io import tiles as tiling
from gfjax.pmf import Config, Params
from gfjax.pmf import stages
from gfjax.tune import pmf as tpmf

from .helpers import crop_batch, crop_sample

CONFIG = Config(max_window_m=17.0)          # windows 3, 5, 9, 17 cells
PARAMS = [Params(), Params(slope=0.3, initial_distance_m=0.5, max_distance_m=1.0),
          Params(slope=2.5, initial_distance_m=0.05, max_distance_m=5.0)]


@functools.cache
def prepared():
    b = crop_batch()
    return tpmf.prepare_tile(b.xyz[0], b.valid[0], b.hw[0], config=CONFIG, shape=b.shape)


@pytest.mark.parametrize("params", PARAMS, ids=["defaults", "low", "high"])
def test_hard_mode_equals_classify_tile(params):
    b = crop_batch()
    plain, _ = stages.classify_tile(b.xyz[0], b.valid[0], b.hw[0], params, config=CONFIG, shape=b.shape)
    got = jax.jit(functools.partial(tpmf.ground_weight, config=CONFIG))(prepared(), params)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(plain))
    assert 0 < int(np.sum(np.asarray(got))) < int(np.sum(b.valid[0]))


@functools.cache
def soft_loss():
    def loss(values, temperature, valid, ref):
        w = tpmf.ground_weight(prepared(), tpmf.make_params(values), config=CONFIG, temperature=temperature)
        return metrics.expected_total_error(metrics.soft_confusion(w, ref, valid))
    return jax.jit(jax.value_and_grad(loss))


def test_check_grads_relaxed_point_test():
    fn = jax.jit(lambda v: jnp.mean(tpmf.ground_weight(prepared(), tpmf.make_params(v), config=CONFIG,
                                                       temperature=0.3)))
    check_grads(fn, (jnp.asarray([1.0, 0.15, 2.5], jnp.float32),), order=1, modes=["fwd", "rev"],
                eps=1e-2, atol=1e-3, rtol=3e-2)


def test_every_parameter_has_a_nonzero_gradient_on_labelled_crop():
    b = crop_batch()
    ref = np.zeros(b.valid.shape[1], bool)
    # The single tile holds every used point, in the tiler's order (`Tile.index`).
    (tile,) = tiling.split(crop_sample().xyz_m, tile_size_m=CONFIG.tile_size_m, buffer_m=CONFIG.buffer_m,
                           cell_m=CONFIG.cell_m, use=crop_sample().use)
    ref[:tile.n_points] = crop_sample().ref_ground[tile.index]
    # At the defaults (slope 1) slope sets only dh_1 = 2.15 m, which is rarely the binding
    # window: its gradient is ~1e-6. At slope 0.3 (dh = 0.15, 0.75, 2.25, 2.5 capped) every
    # parameter binds somewhere.
    loss, grad = soft_loss()(jnp.asarray([0.3, 0.15, 2.5], jnp.float32), jnp.float32(0.1),
                             jnp.asarray(b.valid[0]), jnp.asarray(ref))
    assert np.isfinite(float(loss)) and 0 < float(loss) < 0.5
    assert np.all(np.isfinite(np.asarray(grad))) and np.all(np.abs(np.asarray(grad)) > 1e-5), grad


@pytest.mark.parametrize("all_ground", [True, False])
def test_loss_finite_on_one_class_tiles(all_ground):
    b = crop_batch()
    ref = jnp.full(b.valid.shape[1], all_ground)
    loss, grad = soft_loss()(jnp.asarray([1.0, 0.15, 2.5], jnp.float32), jnp.float32(0.05),
                             jnp.asarray(b.valid[0]), ref)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(grad)))
