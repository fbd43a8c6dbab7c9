"""`dmf.Params` (and every method's `Params`, one base): construction, `--set`-style
replacement, range checks, and `jax.grad` / `jax.jit` / `jax.vmap` through it."""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import dmf, methods
from gfjax import params as params_lib
from gfjax.errors import SettingError


@pytest.mark.parametrize("name", [n for n in methods.PACKAGES if methods.get(n).Params is not None])
def test_every_methods_params_share_one_base_and_check(name):
    method = methods.get(name)
    params = method.Params()
    assert isinstance(params, params_lib.Params)
    for field in dataclasses.fields(params):
        value = getattr(params, field.name)
        assert isinstance(value, jax.Array) and value.dtype == jnp.float32 and value.shape == (), field.name
    params.check()
    first = dataclasses.fields(params)[0].name
    with pytest.raises(SettingError, match=f"^{first} must be") as caught:
        dataclasses.replace(params, **{first: np.nan}).check()
    assert caught.value.keys == (first,)


def test_defaults_are_float32_scalars():
    params = dmf.Params()
    for value, expected in ((params.height_threshold_m, 0.0), (params.height_threshold_w, 0.15)):
        assert value.dtype == np.float32 and value.shape == ()
        assert float(value) == pytest.approx(expected)
    assert float(dmf.Params(height_threshold_m=1, height_threshold_w=np.float64(0.5)).threshold_m(2.0)) == 2.0


def test_leaves_and_replace():
    params = dmf.Params(height_threshold_m=0.25, height_threshold_w=0.5)
    leaves, treedef = jax.tree.flatten(params)
    assert [float(v) for v in leaves] == [0.25, 0.5]
    again = jax.tree.unflatten(treedef, [jnp.float32(1.0), jnp.float32(2.0)])
    assert isinstance(again.height_threshold_m, jax.Array)                # JAX leaves kept
    replaced = dataclasses.replace(params, height_threshold_w=0.75)
    assert replaced.height_threshold_w.dtype == np.float32 and float(replaced.height_threshold_w) == 0.75
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.height_threshold_m = np.float32(1.0)


def test_set_override():
    _, params = methods.make_config_and_params(dmf, {"height_threshold_w": "0.3"})
    assert float(params.threshold_m(2.0)) == pytest.approx(0.6)


def test_grad_jit_vmap_through_params():
    cell_m = 3.0

    def threshold(p):
        return p.threshold_m(cell_m)

    grads = jax.grad(threshold)(dmf.Params(height_threshold_m=0.1, height_threshold_w=0.2))
    assert isinstance(grads, dmf.Params)
    assert float(grads.height_threshold_m) == pytest.approx(1.0)
    assert float(grads.height_threshold_w) == pytest.approx(cell_m)
    assert float(jax.jit(threshold)(dmf.Params())) == pytest.approx(0.45)
    batch = dmf.Params(height_threshold_m=jnp.asarray([0.0, 1.0], jnp.float32),
                       height_threshold_w=jnp.asarray([0.1, 0.2], jnp.float32))
    np.testing.assert_allclose(np.asarray(jax.vmap(threshold)(batch)), [0.3, 1.6], rtol=1e-6)
