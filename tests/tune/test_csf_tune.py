"""Relaxed CSF: hard mode equals `gfjax.csf.filter` bit for bit on every grid cloth; the class
threshold's gradient is correct and non-zero on a labelled crop; losses finite on one-class
labels; `fit`, the guard and `gfjax tune --method csf` drive it, and `gfjax filter --params`
reads what it writes. One cloth shape and one rigidness: two compiles of the simulation."""
from __future__ import annotations

import argparse
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

import gfjax
from gfjax import metrics
from gfjax.cli import main as cli_main
from gfjax.cli._common import method_setup
from gfjax.csf import tuning as tcsf
from gfjax.tune import fit as tfit
from gfjax.tune import guard
from gfjax.tune.problem import Problem

from .helpers import crop_cloud, crop_sample

CONFIG = gfjax.csf.Config()
GRID = (tcsf.encode(0.65, 3), tcsf.encode(0.8, 3))       # time step is traced: one compile


@functools.cache
def csf_problem() -> Problem:
    return Problem([crop_sample()], config=CONFIG, method=tcsf.TUNER, grid=GRID)


def _prep() -> tcsf.Prepared:
    (bucket,) = csf_problem().buckets
    return jax.tree.map(lambda a: a[0], bucket.prep)


def test_grid_codes_round_trip():
    assert tcsf.decode(tcsf.encode(0.65, 3)) == (0.65, 3)
    assert [tcsf.decode(c) for c in tcsf.GRID][:3] == [(0.5, 1), (0.65, 1), (0.8, 1)]
    assert tcsf.TUNER.default_static(CONFIG) == tcsf.encode(0.65, 3) == 30.65
    with pytest.raises(ValueError, match="was not prepared"):
        csf_problem().config.index(tcsf.encode(0.5, 2))


@pytest.mark.parametrize("cloth", range(len(GRID)))
@pytest.mark.parametrize("threshold_m", [0.5, 0.2])
def test_hard_mode_equals_csf_filter(cloth, threshold_m):
    pb = csf_problem()
    time_step, rigidness = tcsf.decode(pb.config.cloths[cloth])
    plain = gfjax.csf.filter(crop_cloud(), config=CONFIG,
                             params=gfjax.csf.Params(class_threshold_m=threshold_m, time_step=time_step)).ground
    assert rigidness == CONFIG.rigidness
    hard = jax.jit(tcsf.ground_weight)(_prep(), jnp.float32(threshold_m), cloth)
    (labels,) = pb.labels([np.asarray(hard)[None]])
    np.testing.assert_array_equal(labels, plain)
    assert 0 < plain.sum() < crop_sample().use.sum()


@functools.cache
def soft_loss():
    def loss(threshold_m, temperature, ref):
        prep = _prep()
        w = tcsf.ground_weight(prep, threshold_m, 0, temperature=temperature)
        return metrics.expected_total_error(metrics.soft_confusion(w, ref, prep.valid))
    return jax.jit(jax.value_and_grad(loss))


def _ref() -> jax.Array:
    (bucket,) = csf_problem().buckets
    return bucket.ref[0]


def test_check_grads_relaxed_class_test():
    prep = _prep()
    fn = jax.jit(lambda t, d: jnp.mean(tcsf.ground_weight(tcsf.Prepared(d, prep.valid), t, 1, temperature=0.2)))
    check_grads(fn, (jnp.float32(0.5), prep.distance), order=1, modes=["fwd", "rev"], eps=1e-2, atol=1e-3,
                rtol=3e-2)
    vmapped = jax.vmap(lambda t: fn(t, prep.distance))(jnp.asarray([0.3, 0.5], jnp.float32))
    np.testing.assert_allclose(np.asarray(vmapped), [float(fn(jnp.float32(t), prep.distance)) for t in (0.3, 0.5)],
                               rtol=1e-6)


def test_threshold_gradient_nonzero_on_labelled_crop():
    loss, grad = soft_loss()(jnp.float32(0.5), jnp.float32(0.05), _ref())
    assert 0 < float(loss) < 0.5 and np.isfinite(float(grad)) and abs(float(grad)) > 1e-4, (loss, grad)


@pytest.mark.parametrize("all_ground", [True, False])
def test_loss_finite_on_one_class_labels(all_ground):
    loss, grad = soft_loss()(jnp.float32(0.5), jnp.float32(0.01), jnp.full(_ref().shape, all_ground))
    assert np.isfinite(float(loss)) and np.isfinite(float(grad))


def test_fit_and_guard_search_the_cloth_grid():
    pb = csf_problem()
    r = tfit.fit(pb, tfit.Settings(steps=4, eval_every=2))
    assert set(r.history) == set(GRID) and r.values.shape == (1, 1)
    assert r.window_m[0] in GRID and 0.1 <= r.values[0, 0] <= 1.5
    assert r.train_error[0] <= r.start_error[0]
    err = tfit.hard_errors(pb, r.values, pb.masks(), np.zeros(1, np.int32), float(r.window_m[0]))[0]
    assert err + 0.01 * tfit._penalty(r.values, tcsf.TUNER)[0] == pytest.approx(r.train_error[0])
    v = guard.validate(pb, tfit.Settings(steps=2, eval_every=2), folds=2, block_m=20.0)
    assert v.values.shape == (1, 1) and v.window_m[0] in GRID and np.isfinite(v.default_error[0])


def test_cli_tune_csf_writes_params_that_filter_reads(tmp_path, capsys):
    laz = tmp_path / "crop.laz"
    gfjax.write(crop_cloud(), laz)
    out = tmp_path / "csf.json"
    code = cli_main.main(["tune", str(laz), "-o", str(out), "--method", "csf", "--steps", "3", "--folds", "0",
                          "--time-steps", "0.65,0.8", "--rigidness", "3"])
    assert code == 0, capsys.readouterr()
    data = json.loads(out.read_text())
    assert data["method"] == "csf" and set(data["values"]) == {"class_threshold_m", "time_step", "rigidness"}
    assert set(data["fitted"]) <= {"class_threshold_m"}
    assert data["grid"] == {"time_step": [0.65, 0.8], "rigidness": [3]}
    assert set(data["not_differentiable"]) == {"time_step", "rigidness"}
    setup = method_setup(argparse.Namespace(params=str(out), method=None, preset=None, set_values=[]))
    # the grid's cloth, or the start's: the soft cloth that follows the data (`csf.adapt`)
    assert setup.name == "csf" and setup.config.rigidness == data["values"]["rigidness"] in (3, 1)
    from gfjax import adaptive, csf

    assert data["start"]["chosen_from_terrain"] == csf.adapt(adaptive.measure(gfjax.read(laz).xyz_m))
    assert np.float32(setup.params.time_step) == np.float32(data["values"]["time_step"])
    assert np.float32(setup.params.class_threshold_m) == np.float32(data["values"]["class_threshold_m"])
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "p.json"), "--method", "smrf",
                          "--rigidness", "2"]) == 2
