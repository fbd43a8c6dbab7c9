"""`gfjax.params.f32`: every kind of value becomes a float32 JAX array, host values without a
compiled conversion."""
import logging

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.params import f32


@pytest.mark.parametrize("value", [0.15, 3, np.float64(0.1), np.array([0.2, 1e-8, 7.0]), np.int32(4), True])
def test_host_values_round_as_jax_does(value):
    out = f32(value)
    assert isinstance(out, jax.Array) and out.dtype == jnp.float32
    np.testing.assert_array_equal(np.asarray(out), np.asarray(jnp.asarray(value, dtype=jnp.float32)))


def test_jax_values_and_tracers_convert_in_place():
    assert f32(jnp.array(2, jnp.int32)).dtype == jnp.float32
    assert float(jax.jit(lambda x: f32(x) * 2)(1.5)) == 3.0
    np.testing.assert_array_equal(jax.vmap(f32)(jnp.arange(3)), np.arange(3, dtype=np.float32))
    assert float(jax.grad(lambda x: f32(x) ** 2)(3.0)) == 6.0


def test_a_host_value_compiles_nothing(caplog):
    f32(0.5)                                    # the backend's own start-up, once
    with jax.log_compiles(), caplog.at_level(logging.WARNING, logger="jax"):
        f32(0.25)
        f32(np.array([1.0, 2.0]))
    assert not [r for r in caplog.records if "ompil" in r.getMessage()]
