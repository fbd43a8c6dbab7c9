"""Relaxed SMRF: hard mode equals the plain filter bit for bit; relaxed stages have correct,
non-zero gradients; losses are finite on all-ground and no-ground tiles."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import gfjax
from gfjax.smrf import Params, programs, stages
from gfjax.smrf import tuning as tsmrf
from gfjax.tune import fit as tfit
from gfjax.tune import params as tparams

from .helpers import CONFIG, crop_batch, crop_cloud, crop_prepared, problem

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

PARAMS = [Params(), Params(slope=0.3, threshold_m=0.2, scalar=0.0), Params(slope=0.05, threshold_m=0.9, scalar=2.5)]


@functools.cache
def hard_weight():
    return jax.jit(functools.partial(tsmrf.ground_weight, config=CONFIG))


@pytest.mark.parametrize("params", PARAMS, ids=["defaults", "steep", "flat"])
@pytest.mark.parametrize("window_m", [4.0, 6.0])
def test_hard_mode_equals_classify_tile(params, window_m):
    b = crop_batch()
    config = CONFIG.__class__(**{**CONFIG.__dict__, "window_m": window_m})
    plain, diag = programs.classify_tile(b.xyz[0], b.valid[0], b.hw[0], params, config=config, shape=b.shape)
    got = hard_weight()(crop_prepared(), params, radius_px=tsmrf.radius_for(CONFIG, window_m))
    assert got.dtype == jnp.bool_
    np.testing.assert_array_equal(np.asarray(got), np.asarray(plain))
    assert 0 < int(np.sum(np.asarray(got))) < int(np.sum(b.valid[0]))


def test_hard_evaluation_equals_smrf_filter():
    """The tuning problem's hard labels equal `gfjax.smrf.filter` on the whole cloud."""
    cloud = crop_cloud()
    plain = gfjax.smrf.filter(cloud, config=CONFIG).ground
    pb = problem(("crop",))
    bucket = pb.buckets[0]
    weights = jax.vmap(hard_weight(), in_axes=(0, None))(bucket.prep, Params())
    (labels,) = pb.labels([np.asarray(weights)])
    np.testing.assert_array_equal(labels, plain)
    errs = tfit.hard_errors(pb, tsmrf.TUNER.defaults[None, :], pb.masks(), np.zeros(1, np.int32), CONFIG.window_m)
    ref = pb.samples[0].ref_ground
    np.testing.assert_allclose(errs[0], np.mean(plain != ref), rtol=1e-12)


def test_relaxed_tends_to_hard_at_low_temperature():
    prep = crop_prepared()
    hard = np.asarray(hard_weight()(prep, Params()))
    soft = np.asarray(jax.jit(functools.partial(tsmrf.ground_weight, config=CONFIG, temperature=1e-3))(prep, Params()))
    valid = np.asarray(prep.valid)
    assert np.mean((soft[valid] > 0.5) == hard[valid]) > 0.99


def test_check_grads_soft_inpaint():
    rng = np.random.default_rng(0)
    z = jnp.asarray(rng.normal(0, 1, (8, 9)), jnp.float32)
    keep = rng.choice([0.1, 0.3, 0.7, 0.95], size=(8, 9)).astype(np.float32)
    fn = jax.jit(functools.partial(tsmrf.soft_inpaint, config=CONFIG, sweeps=6))
    check_grads(fn, (z, jnp.asarray(keep)), order=1, modes=["fwd", "rev"], eps=1e-2, atol=2e-2, rtol=2e-2)


def test_soft_inpaint_with_hard_weights_is_the_harmonic_fill():
    rng = np.random.default_rng(1)
    z = jnp.asarray(rng.normal(0, 1, (12, 10)), jnp.float32)
    known = rng.random((12, 10)) < 0.6
    filled = stages.inpaint(z, jnp.asarray(known), config=CONFIG)
    soft = tsmrf.soft_inpaint(z, jnp.asarray(known, jnp.float32), config=CONFIG, sweeps=4)
    np.testing.assert_allclose(np.asarray(soft), np.asarray(filled), atol=5e-3)


def test_check_grads_relaxed_object_test():
    prep = crop_prepared()
    fn = jax.jit(lambda slope: jnp.sum(tsmrf._object_cells(prep, slope, jnp.int32(6), CONFIG.cell_m, 0.3)))
    check_grads(fn, (jnp.float32(0.15),), order=1, modes=["fwd", "rev"], eps=1e-2, atol=1e-1, rtol=2e-2)


def test_check_grads_relaxed_point_test():
    """threshold and scalar act only at the point test (ZIpro does not depend on them)."""
    prep = crop_prepared()

    @jax.jit
    def fn(threshold_m, scalar):
        w = tsmrf.ground_weight(prep, Params(slope=0.15, threshold_m=threshold_m, scalar=scalar), config=CONFIG,
                                temperature=0.2)
        return jnp.mean(w)

    check_grads(fn, (jnp.float32(0.5), jnp.float32(1.25)), order=1, modes=["rev"], eps=1e-2, atol=1e-3, rtol=3e-2)


def _loss_and_grad(pb, raw, kind, temperature=0.1):
    c = pb.n_samples
    return tfit._soft_value_and_grad(raw, jnp.int32(6), jnp.float32(temperature), tfit._arrays(pb), pb.masks(),
                                     jnp.zeros(c, jnp.int32), jnp.full(c, 1.0 / c, jnp.float32), jnp.float32(0.0),
                                     config=pb.config, kind=kind, n_samples=c, method=pb.method)


def test_every_fitted_parameter_has_a_nonzero_gradient_on_labelled_sample():
    pb = problem(("crop",))
    raw = tparams.to_raw({b.name: b.default for b in tsmrf.BOUNDS}, tsmrf.BOUNDS)[None, :]
    loss, grad = _loss_and_grad(pb, raw, "total-error")
    assert np.isfinite(float(loss)) and 0 < float(loss) < 0.5
    grad = np.asarray(grad)[0]
    assert np.all(np.isfinite(grad))
    assert np.all(np.abs(grad) > 1e-5), dict(zip([b.name for b in tsmrf.BOUNDS], grad))


@pytest.mark.parametrize("kind", tfit.LOSSES)
def test_losses_finite_on_all_ground_and_no_ground_tiles(kind):
    pb = problem(("flat", "roof", "rough"))          # all-ground, no-ground, rough ground
    for raw in (jnp.zeros((1, 3), jnp.float32), jnp.full((1, 3), 4.0, jnp.float32)):
        loss, grad = _loss_and_grad(pb, raw, kind)
        assert np.isfinite(float(loss))
        assert np.all(np.isfinite(np.asarray(grad)))
