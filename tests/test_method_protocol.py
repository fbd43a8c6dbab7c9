"""Every registered method keeps the `gfjax.method.Method` protocol, checked the same way for
each (the values the CLI, surveys, warm-up, tuning and the option table read)."""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import sys
import types

import numpy as np
import pytest

from gfjax import adaptive, methods
from gfjax.errors import InputError
from gfjax.limits import Range
from gfjax.method import TUNINGS, Method
from gfjax.params import Params
from gfjax.result import Result

NAMES = methods.names()
FILTER_ARGS = ["cloud", "config", "params", "returns", "progress"]


@pytest.mark.parametrize("name", NAMES)
def test_the_package_exports_its_method_under_its_registered_name(name):
    method = methods.get(name)
    assert isinstance(method, Method) and method.name == name
    assert importlib.import_module(methods.PACKAGES[name]).METHOD is method
    assert methods.of(name) is method and methods.of(importlib.import_module(methods.PACKAGES[name])) is method


@pytest.mark.parametrize("name", NAMES)
def test_filter_takes_the_common_arguments_and_exactly_its_options(name):
    method = methods.get(name)
    parameters = inspect.signature(method.filter).parameters
    assert list(parameters)[:len(FILTER_ARGS)] == FILTER_ARGS
    options = set(list(parameters)[len(FILTER_ARGS):])
    assert options == {key for key, taken in (("tiling", method.tiles), ("model", method.load_model),
                                              ("terrain", method.takes_terrain), ("core", method.takes_core))
                       if taken}
    assert all(parameters[k].kind is inspect.Parameter.KEYWORD_ONLY for k in FILTER_ARGS[1:] + sorted(options))


@pytest.mark.parametrize("name", NAMES)
def test_a_tunable_method_keeps_its_tuner_in_its_own_package(name):
    from gfjax.tune import search, tuners

    method = methods.get(name)
    if method.tuning is None:
        with pytest.raises(ValueError, match="cannot be tuned"):
            tuners.get(name)
        return
    tuner = importlib.import_module(f"{methods.PACKAGES[name]}.tuning").TUNER
    kind = {"gradient": tuners.GradientTuner, "grid": search.GridTuner}[method.tuning]
    assert isinstance(tuner, kind) and tuner.name == name and tuners.get(name) is tuner
    assert tuner.config_type is method.Config


@pytest.mark.parametrize("name", NAMES)
def test_config_params_presets_and_ranges_fit_together(name):
    method = methods.get(name)
    config = method.Config()
    assert dataclasses.is_dataclass(config) and method.Config.__dataclass_params__.frozen
    assert isinstance(methods.memory_estimates(config), list)
    if method.Params is not None:
        assert issubclass(method.Params, Params) and method.Params.ranges is method.ranges
    for preset, values in method.presets.items():
        methods.make_config_and_params(method, preset=preset)
        assert set(values) <= set(method.ranges) | {f.name for f in dataclasses.fields(config)}, preset
    assert method.tuning in (None, *TUNINGS)


@pytest.mark.parametrize("name", [n for n in NAMES if methods.get(n).adapt is not None])
def test_adapt_names_only_fields_the_options_can_set(name):
    method = methods.get(name)
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(0, 200, (20_000, 2)), rng.normal(0, 0.02, 20_000)])
    chosen = method.adapt(adaptive.measure(xyz))
    fields = {f.name for f in dataclasses.fields(method.Config)}
    fields |= {f.name for f in dataclasses.fields(method.Params)} if method.Params is not None else set()
    assert isinstance(chosen, dict) and set(chosen) <= fields
    methods.make_config_and_params(method, values=chosen)          # in range, and accepted


def test_the_flags_agree():
    for name in NAMES:
        method = methods.get(name)
        assert not method.tile_labels or method.tiles, name
        assert not (method.whole_cloud and method.tile_labels), name
    with pytest.raises(ValueError, match="tile_labels needs tiles"):
        Method("bad", print, methods.get("smrf").Config, None, {}, {}, tile_labels=True)
    with pytest.raises(ValueError, match="tuning must be one of"):
        Method("bad", print, methods.get("smrf").Config, None, {}, {}, tuning="by hand")
    with pytest.raises(ValueError, match=r"ranges of keys that are no field: \['nope'\]"):
        Method("bad", print, methods.get("smrf").Config, None, {}, {"nope": Range(0, 1)})


def test_a_seventh_method_is_its_package_and_one_registry_line(monkeypatch):
    """A toy package exporting METHOD, registered by one entry of `PACKAGES`: the CLI's
    choices, the option table and `gfjax.<name>`-style lookups all see it."""
    from gfjax.cli import ranges

    @dataclasses.dataclass(frozen=True)
    class Config:
        threshold_m: float = 0.5

        def memory_estimates(self, extent_m=None):
            return []

    def filter(cloud, *, config=None, params=None, returns="all", progress=False):  # noqa: A001
        z = cloud.xyz_m[:, 2]
        return Result(ground=z <= z.min() + (config or Config()).threshold_m, diagnostics=None)

    package = types.ModuleType("toy_method")
    package.METHOD = Method("toy", filter, Config, None, {"strict": {"threshold_m": 0.1}},
                            {"threshold_m": Range(0, 10, unit="m")})
    monkeypatch.setitem(sys.modules, "toy_method", package)
    monkeypatch.setitem(methods.PACKAGES, "toy", "toy_method")         # the one registry line

    assert "toy" in methods.names() and "toy" in methods.available()
    assert methods.get("toy") is package.METHOD
    assert "| toy | `threshold_m` | >= 0 and <= 10 m | 0.5 |" in ranges.markdown_table()
    config, _ = methods.make_config_and_params("toy", {"threshold_m": "0.2"}, "strict")
    assert config.threshold_m == 0.2
    with pytest.raises(InputError, match="unknown preset 'loose' for toy; choose from strict"):
        methods.make_config_and_params("toy", preset="loose")


def test_a_method_imports_with_the_collector_paused_and_leaves_it_as_it_was(monkeypatch):
    """The collector is off while a method's package imports, and after it as before: on, or
    off where the caller had turned it off, also when the import fails."""
    import gc

    seen, real_import = [], importlib.import_module

    def import_module(name):
        seen.append(gc.isenabled())
        if name == "missing_method":
            raise ModuleNotFoundError(name=name)
        return real_import(name)

    monkeypatch.setattr(methods.importlib, "import_module", import_module)
    monkeypatch.setitem(methods.PACKAGES, "missing", "missing_method")
    assert gc.isenabled()
    methods.get("smrf")
    assert seen == [False] and gc.isenabled()
    with pytest.raises(InputError, match="method 'missing' is not available in this build"):
        methods.get("missing")
    assert seen == [False, False] and gc.isenabled()
    gc.disable()
    try:
        methods.get("smrf")
        assert not gc.isenabled()
    finally:
        gc.enable()
