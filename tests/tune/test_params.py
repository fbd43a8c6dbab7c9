"""Bounded parametrisation, prior, and the params.json round trip through the CLI layer."""
from __future__ import annotations

import argparse
import json

import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from gfjax import methods
from gfjax.cli._common import load_params_file, method_setup
from gfjax.errors import InputError
from gfjax.smrf import tuning as tsmrf
from gfjax.tune import params as tparams

B = tsmrf.BOUNDS


def test_raw_round_trip_and_bounds():
    values = {"slope": 0.3, "threshold_m": 0.25, "scalar": 2.0}
    back = np.asarray(tparams.from_raw(tparams.to_raw(values, B), B))
    np.testing.assert_allclose(back, [0.3, 0.25, 2.0], rtol=1e-5)
    extreme = np.asarray(tparams.from_raw(jnp.asarray([[-50.0, 0.0, 50.0]], jnp.float32), B))[0]
    assert B[0].lo <= extreme[0] <= B[0].hi and B[2].lo <= extreme[2] <= B[2].hi
    np.testing.assert_allclose(extreme[[0, 2]], [B[0].lo, B[2].hi], atol=1e-6)


def test_prior_zero_at_defaults_and_differentiable():
    raw0 = tparams.to_raw({b.name: b.default for b in B}, B)
    assert float(tparams.prior_penalty(raw0, B)) < 1e-10
    raw = raw0 + jnp.asarray([0.5, -0.3, 0.2], jnp.float32)
    assert float(tparams.prior_penalty(raw, B)) > 0
    check_grads(lambda r: tparams.prior_penalty(r, B), (raw,), order=1, modes=["rev"], eps=1e-2, rtol=2e-2)


def test_params_json_round_trip_through_filter_params(tmp_path):
    values = {"slope": np.float32(0.2173), "threshold_m": np.float32(0.41), "scalar": np.float32(0.9),
              "window_m": 12.0}
    path = tparams.write_params(tmp_path / "p.json", method="smrf", values=values, units=tsmrf.UNITS,
                                extra={"fitted": ["slope"]})
    data = json.loads(path.read_text())
    assert set(data) >= {"method", "gfjax_version", "units", "values"}
    assert tparams.read_params(path)["values"] == data["values"]
    assert load_params_file(path)["method"] == "smrf"                      # the CLI's reader
    args = argparse.Namespace(params=str(path), method=None, preset=None, set_values=[])
    setup = method_setup(args)                                              # `gfjax filter --params`
    assert setup.name == "smrf" and setup.config.window_m == 12.0
    for key in ("slope", "threshold_m", "scalar"):                          # float32 bit for bit
        assert np.float32(getattr(setup.params, key)) == np.float32(values[key])
    config, params = methods.make_config_and_params(methods.get("smrf"), values=data["values"])
    assert float(params.slope) == float(np.float32(0.2173))


def test_bad_params_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputError, match="bad.json"):
        tparams.read_params(bad)
    bad.write_text(json.dumps({"method": "smrf", "values": {"slope": "x"}}))
    with pytest.raises(InputError, match="slope"):
        tparams.read_params(bad)
    with pytest.raises(InputError, match="no such file"):
        tparams.read_params(tmp_path / "missing.json")
    with pytest.raises(ValueError, match="finite"):
        tparams.write_params(tmp_path / "p.json", method="smrf", values={"slope": float("nan")}, units=tsmrf.UNITS)
    with pytest.raises(ValueError, match="overwrite"):
        tparams.write_params(tmp_path / "p.json", method="smrf", values={"slope": 0.1}, units=tsmrf.UNITS,
                             extra={"values": 1})
