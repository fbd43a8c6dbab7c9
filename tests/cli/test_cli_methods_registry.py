"""`gfjax.methods`: method lookup and Config/Params from presets, params.json values and --set."""
from __future__ import annotations

import dataclasses
import types
from typing import Any

import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import methods
from gfjax.errors import InputError
from gfjax.method import Method


@dataclasses.dataclass(frozen=True)
class Config:
    cell_m: float = 1.0
    max_iter: int = 10
    fill: bool = True
    mode: str = "harmonic"

    def __post_init__(self):
        if not self.cell_m > 0:
            raise ValueError(f"cell_m must be > 0, got {self.cell_m!r}")


@dataclasses.dataclass(frozen=True)
class Params:
    slope: Any = dataclasses.field(default_factory=lambda: jnp.asarray(0.15, jnp.float32))


MODULE = types.ModuleType("gfjax.toy")        # a method package: `make_config_and_params` takes it or its METHOD
MODULE.METHOD = Method("toy", lambda cloud, **kwargs: None, Config, Params, {"steep": {"slope": 0.3, "cell_m": 2.0}}, {})


def test_types_follow_the_fields():
    config, params = methods.make_config_and_params(
        MODULE, {"max_iter": "20", "fill": "off", "mode": "nearest", "slope": "0.25"})
    assert (config.max_iter, config.fill, config.mode) == (20, False, "nearest")
    assert params.slope.dtype == jnp.float32 and float(params.slope) == np.float32(0.25)


def test_none_turns_an_optional_value_off_and_is_refused_where_a_value_is_needed():
    from gfjax import csf, masf

    config, _ = methods.make_config_and_params(masf, {"mirror_max_m": "none"})
    assert config.mirror_max_m is None
    config, _ = methods.make_config_and_params(csf, {"trend_m": "None"})
    assert config.trend_m is None
    with pytest.raises(InputError, match="cell_m"):           # its range (under test, also its type hint)
        methods.make_config_and_params(csf, {"cell_m": "none"})
    with pytest.raises(InputError, match="--set slope=none: could not convert"):
        methods.make_config_and_params(MODULE, {"slope": "none"})


def test_precedence_defaults_preset_values_set():
    config, params = methods.make_config_and_params(MODULE, preset="steep")
    assert (config.cell_m, float(params.slope)) == (2.0, np.float32(0.3))
    config, params = methods.make_config_and_params(MODULE, preset="steep", values={"slope": 0.4, "max_iter": 30.0})
    assert (config.cell_m, config.max_iter, float(params.slope)) == (2.0, 30, np.float32(0.4))
    assert isinstance(config.max_iter, int)
    config, params = methods.make_config_and_params(MODULE, {"slope": "0.5"}, "steep", values={"slope": 0.4})
    assert float(params.slope) == np.float32(0.5)


@pytest.mark.parametrize("kwargs,message", [
    ({"overrides": {"nope": "1"}}, "--set: unknown key 'nope' for method toy; known keys: cell_m, fill, max_iter, mode, slope"),
    ({"overrides": {"max_iter": "2.5"}}, "--set max_iter=2.5: invalid literal"),
    ({"overrides": {"fill": "maybe"}}, "--set fill=maybe: expected true/false"),
    ({"overrides": {"cell_m": "-1"}}, "--set: cell_m must be > 0, got -1.0"),
    ({"values": {"max_iter": 2.5}, "values_source": "--params p.json"}, "--params p.json max_iter=2.5: expected an integer"),
    ({"values": {"zzz": 1.0}, "values_source": "--params p.json"}, "--params p.json: unknown key 'zzz'"),
    ({"preset": "flat"}, "--preset: unknown preset 'flat' for toy; choose from steep"),
])
def test_errors_name_the_option(kwargs, message):
    with pytest.raises(InputError) as err:
        methods.make_config_and_params(MODULE, **kwargs)
    assert str(err.value).startswith(message)


def test_get_unknown_and_unavailable_methods(monkeypatch):
    with pytest.raises(InputError, match="--method: unknown method 'zzz'; choose from smrf"):
        methods.get("zzz")
    monkeypatch.setitem(methods.PACKAGES, "ghost", "gfjax._ghost_method")
    with pytest.raises(InputError, match="method 'ghost' is not available in this build"):
        methods.get("ghost")
    assert "ghost" not in methods.available()
    assert methods.DEFAULT_METHOD in methods.PACKAGES
