"""Fuzzing the files a user hands gfjax besides point clouds: params.json (`--params`) and
SparseGF model files (`--model`). Whatever their bytes, reading them ends in a usable setting
or an `InputError` / `SettingError` naming the file (exit 2), never another exception."""
from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gfjax import methods
from gfjax.cli._common import method_setup
from gfjax.cli.main import build_parser
from gfjax.errors import InputError, SettingError
from gfjax.sparsegf import checkpoint
from gfjax.sparsegf.features import n_features
from gfjax.sparsegf.model import NetConfig, init

USER_ERRORS = (InputError, SettingError)
KEYS = sorted({f for name in methods.names() for f in methods.get(name).ranges} | {"window_m", "nonsense"})
numbers = st.one_of(st.integers(-10 ** 12, 10 ** 12), st.floats(allow_nan=True, allow_infinity=True), st.booleans())
json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                                      max_size=3),
                           max_leaves=8)


def setup_from(params_path, method: str | None):
    argv = ["filter", "in.las", "-o", "out.laz", "--params", str(params_path), *(["--method", method] if method else [])]
    parser, _ = build_parser(argv)
    return method_setup(parser.parse_args(argv))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(method=st.sampled_from(["smrf", "pmf", "csf", "dmf", "masf", "sparsegf", "nope", ""]),
       values=st.dictionaries(st.sampled_from(KEYS), numbers | json_values, max_size=4),
       extra=st.dictionaries(st.text(max_size=6), json_values, max_size=2),
       given_method=st.sampled_from([None, "smrf", "csf"]))
def test_a_params_document_of_any_shape_is_used_or_refused_as_the_users(tmp_path_factory, method, values, extra,
                                                                         given_method):
    path = tmp_path_factory.mktemp("params") / "params.json"
    path.write_text(json.dumps({"method": method, "values": values, **extra}, allow_nan=True))
    try:
        setup = setup_from(path, given_method)
    except USER_ERRORS as err:
        assert str(path) in str(err) or "--set" in str(err) or "--params" in str(err), err
        return
    for key, value in values.items():                        # what was accepted was taken as it was
        for holder in (setup.config, setup.params):
            if holder is not None and hasattr(holder, key) and key in setup.fixed:
                assert float(np.asarray(getattr(holder, key))) == pytest.approx(float(value), rel=1e-6)


@settings(max_examples=60, deadline=None)
@given(data=st.binary(max_size=300))
def test_params_bytes_of_any_kind_are_refused_naming_the_file(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("bytes") / "params.json"
    path.write_bytes(data)
    try:
        setup_from(path, None)
    except USER_ERRORS as err:
        assert str(path) in str(err) or "--params" in str(err)


MICRO = NetConfig(stem=4, planes=(4,) * 8, layers=(1,) * 8, refine=4, point=4, in_features=n_features("xyz+tophat"))


@pytest.fixture(scope="module")
def model_bytes(tmp_path_factory):
    path = tmp_path_factory.mktemp("model") / "m.eqx"
    checkpoint.save(path, init(MICRO, key=jax.random.key(0)), {"seed": 0})
    return path.read_bytes()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=4),
       cut=st.one_of(st.none(), st.floats(0, 1)))
def test_a_model_file_with_changed_or_missing_bytes_loads_or_is_refused(model_bytes, tmp_path_factory, edits, cut):
    data = bytearray(model_bytes)
    for where, byte in edits:
        data[min(int(where * len(data)), len(data) - 1)] = byte
    if cut is not None:
        data = data[:int(cut * len(data))]
    path = tmp_path_factory.mktemp("models") / "m.eqx"
    path.write_bytes(bytes(data))
    try:
        checkpoint.load(path)
    except InputError as err:
        assert str(path) in str(err)
