"""Relaxed thresholds: hard mode equals the comparison, soft mode tends to it, gradients."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax.tune import relax

H = np.array([-1.0, -0.1, 0.0, 0.0, 0.2, 3.0], np.float32)
T = np.array([0.0, 0.0, 0.0, 0.5, 0.1, 1.0], np.float32)


def test_hard_equals_comparison():
    np.testing.assert_array_equal(np.asarray(relax.greater(jnp.asarray(H), jnp.asarray(T))), H > T)
    np.testing.assert_array_equal(np.asarray(relax.less_equal(jnp.asarray(H), jnp.asarray(T))), H <= T)
    margins = np.stack([H - T, T - H - 5])
    np.testing.assert_array_equal(np.asarray(relax.soft_or_max(jnp.asarray(margins))), np.any(margins > 0, axis=0))


@pytest.mark.parametrize("fn,hard", [(relax.greater, np.greater), (relax.less_equal, np.less_equal)])
def test_soft_tends_to_hard_away_from_threshold(fn, hard):
    soft = np.asarray(jax.jit(fn)(jnp.asarray(H), jnp.asarray(T), jnp.float32(1e-3)))
    away = np.abs(H - T) > 0.05
    np.testing.assert_allclose(soft[away], hard(H, T)[away].astype(np.float32), atol=1e-6)
    np.testing.assert_allclose(soft[~away], 0.5)                       # at the threshold
    assert np.all((soft >= 0) & (soft <= 1))


def test_soft_or_max_is_sigmoid_of_largest_margin_and_bounded_by_noisy_or():
    m = jnp.asarray(np.random.default_rng(0).normal(0, 1, (5, 7)), jnp.float32)
    p = jax.nn.sigmoid(m / 0.3)
    got = relax.soft_or_max(m, 0.3)
    np.testing.assert_allclose(np.asarray(got), np.asarray(jnp.max(p, axis=0)), rtol=1e-6)
    assert np.all(np.asarray(got) <= np.asarray(1 - jnp.prod(1 - p, axis=0)) + 1e-6)


def test_vmap_matches_loop():
    h = jnp.asarray(np.random.default_rng(1).normal(0, 1, (3, 8)), jnp.float32)
    got = jax.vmap(lambda x: relax.greater(x, jnp.float32(0.2), 0.1))(h)
    for i in range(3):
        np.testing.assert_array_equal(np.asarray(got[i]), np.asarray(relax.greater(h[i], jnp.float32(0.2), 0.1)))


@pytest.mark.parametrize("fn", [relax.greater, relax.less_equal])
def test_check_grads_threshold_tests(fn):
    h = jnp.asarray([-0.3, 0.05, 0.4], jnp.float64 if jax.config.jax_enable_x64 else jnp.float32)
    check_grads(lambda h, t, temp: fn(h, t, temp), (h, jnp.full_like(h, 0.1), jnp.ones((), h.dtype) * 0.2),
                order=2, modes=["fwd", "rev"], eps=1e-2, atol=2e-2, rtol=2e-2)


def test_check_grads_soft_or_max():
    m = jnp.asarray([[-0.3, 0.2], [0.1, -0.5], [-0.2, -0.1]], jnp.float32)
    check_grads(lambda m, temp: relax.soft_or_max(m, temp), (m, jnp.float32(0.3)), order=1,
                modes=["fwd", "rev"], eps=1e-2, atol=2e-2, rtol=2e-2)


def test_bad_temperature_and_schedule():
    with pytest.raises(ValueError, match="temperature"):
        relax.greater(jnp.zeros(2), jnp.zeros(2), 0.0)
    s = np.asarray(relax.geometric_schedule(1.0, 0.05, 5))
    np.testing.assert_allclose([s[0], s[-1]], [1.0, 0.05], rtol=1e-6)
    assert np.all(np.diff(s) < 0)
    np.testing.assert_allclose(np.asarray(relax.geometric_schedule(1.0, 0.05, 1)), [0.05])
    with pytest.raises(ValueError):
        relax.geometric_schedule(0.0, 0.05, 3)
