"""`gfjax.params`: every kind of value becomes a float32 JAX array, host values without a
compiled conversion; `Params` is a frozen pytree that JAX rebuilds without converting."""
import dataclasses
import logging
import pickle
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import smrf
from gfjax.params import Params, f32, param


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


class Toy(Params):
    a: jax.Array = param(0.25)
    b: jax.Array = param(2.0)


def test_fields_convert_when_built_and_stay_frozen():
    toy = Toy(b=3)
    assert all(isinstance(v, jax.Array) and v.dtype == jnp.float32 for v in (toy.a, toy.b))
    assert (float(toy.a), float(toy.b)) == (0.25, 3.0)
    assert float(dataclasses.replace(toy, a=1).a) == 1.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        toy.a = 1.0
    assert repr(toy) == "Toy(a=0.25, b=3)"


def test_jax_rebuilds_params_from_any_leaves_without_converting():
    toy = Toy()
    paths = [jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_flatten_with_path(toy)[0]]
    assert paths == [".a", ".b"]
    assert jax.tree.map(lambda _: None, toy).a is None              # a placeholder stays one
    assert jax.tree.map(lambda _: "x", toy).b == "x"
    assert float(jax.jit(lambda t: t.a * t.b)(toy)) == 0.5
    grads = jax.grad(lambda t: t.a * t.b)(toy)
    assert isinstance(grads, Toy) and (float(grads.a), float(grads.b)) == (2.0, 0.25)
    batch = Toy(a=jnp.arange(3.0), b=jnp.ones(3))
    np.testing.assert_array_equal(jax.vmap(lambda t: t.a + t.b)(batch), [1.0, 2.0, 3.0])


def test_params_and_their_tree_definition_survive_pickling():
    """The program store keeps programs whose arguments or results are `Params` (`gfjax.aot`)."""
    toy = Toy(a=0.5)
    again = pickle.loads(pickle.dumps(toy))
    assert isinstance(again, Toy) and float(again.a) == 0.5
    tree = pickle.loads(pickle.dumps(jax.tree_util.tree_structure(smrf.Params())))
    assert tree.unflatten([1.0, 2.0, 3.0]).threshold_m == 2.0


def test_a_classical_filter_does_not_import_equinox():
    code = ("import sys, gfjax.cli.main, gfjax.smrf.filter, gfjax.dmf.filter, gfjax.vote.filter; "
            "print('equinox' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
