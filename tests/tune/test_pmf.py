"""Relaxed PMF: hard mode equals the plain filter bit for bit; gradients of all three
parameters are correct and non-zero on a labelled crop; losses finite on one-class tiles;
`fit` and `gfjax tune --method pmf` drive it."""
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
from gfjax.pmf import Config, Params, programs
from gfjax.pmf import tuning as tpmf
from gfjax.tiling import tiles as tiling
from gfjax.tune import fit as tfit
from gfjax.tune.problem import Problem

from .helpers import crop_batch, crop_cloud, crop_sample

CONFIG = Config(max_window_m=17.0)          # windows 3, 5, 9, 17 cells
PARAMS = [Params(), Params(slope=0.3, initial_distance_m=0.5, max_distance_m=1.0),
          Params(slope=2.5, initial_distance_m=0.05, max_distance_m=5.0)]


@functools.cache
def prepared():
    b = crop_batch()
    return tpmf.prepare_tile(b.xyz[0], b.valid[0], b.hw[0], config=CONFIG, shape=b.shape)


@pytest.mark.parametrize("params", PARAMS, ids=["defaults", "low", "high"])
def test_hard_mode_equals_classify_tile(params):
    b = crop_batch()
    plain, _ = programs.classify_tile(b.xyz[0], b.valid[0], b.hw[0], params, config=CONFIG, shape=b.shape)
    got = jax.jit(functools.partial(tpmf.ground_weight, config=CONFIG))(prepared(), params)
    np.testing.assert_array_equal(np.asarray(got), np.asarray(plain))
    assert 0 < int(np.sum(np.asarray(got))) < int(np.sum(b.valid[0]))


@functools.cache
def soft_loss():
    def loss(values, temperature, valid, ref):
        w = tpmf.ground_weight(prepared(), tpmf.make_params(values), config=CONFIG, temperature=temperature)
        return metrics.expected_total_error(metrics.soft_confusion(w, ref, valid))
    return jax.jit(jax.value_and_grad(loss))


def test_check_grads_relaxed_point_test():
    fn = jax.jit(lambda v: jnp.mean(tpmf.ground_weight(prepared(), tpmf.make_params(v), config=CONFIG,
                                                       temperature=0.3)))
    check_grads(fn, (jnp.asarray([1.0, 0.15, 2.5], jnp.float32),), order=1, modes=["fwd", "rev"],
                eps=1e-2, atol=1e-3, rtol=3e-2)


def test_every_parameter_has_a_nonzero_gradient_on_labelled_crop():
    b = crop_batch()
    ref = np.zeros(b.valid.shape[1], bool)
    # The single tile holds every used point, in the tiler's order (`Tile.index`).
    (tile,) = tiling.split(crop_sample().xyz_m, **tiling.Tiling().lattice(CONFIG.cell_m)._asdict(), use=crop_sample().use)
    ref[:tile.n_points] = crop_sample().ref_ground[tile.index]
    # At the defaults (slope 1) slope sets only dh_1 = 2.15 m, which is rarely the binding
    # window: its gradient is ~1e-6. At slope 0.3 (dh = 0.15, 0.75, 2.25, 2.5 capped) every
    # parameter binds somewhere.
    loss, grad = soft_loss()(jnp.asarray([0.3, 0.15, 2.5], jnp.float32), jnp.float32(0.1),
                             jnp.asarray(b.valid[0]), jnp.asarray(ref))
    assert np.isfinite(float(loss)) and 0 < float(loss) < 0.5
    assert np.all(np.isfinite(np.asarray(grad))) and np.all(np.abs(np.asarray(grad)) > 1e-5), grad


@pytest.mark.parametrize("all_ground", [True, False])
def test_loss_finite_on_one_class_tiles(all_ground):
    b = crop_batch()
    ref = jnp.full(b.valid.shape[1], all_ground)
    loss, grad = soft_loss()(jnp.asarray([1.0, 0.15, 2.5], jnp.float32), jnp.float32(0.05),
                             jnp.asarray(b.valid[0]), ref)
    assert np.isfinite(float(loss)) and np.all(np.isfinite(np.asarray(grad)))


@functools.cache
def pmf_problem() -> Problem:
    return Problem([crop_sample()], config=CONFIG, method=tpmf.TUNER)


def test_problem_hard_labels_equal_pmf_filter_and_fit_improves_training_error():
    pb = pmf_problem()
    one = np.zeros(1, np.int32)
    plain = gfjax.pmf.filter(crop_cloud(), config=CONFIG).ground
    (labels,) = pb.labels(tfit.hard_ground(pb, tpmf.TUNER.defaults[None, :], one, CONFIG.max_window_m))
    np.testing.assert_array_equal(labels, plain)
    r = tfit.fit(pb, tfit.Settings(steps=4, eval_every=2))
    assert r.window_m[0] == CONFIG.max_window_m and set(r.history) == {CONFIG.max_window_m}
    lo, hi = (np.array([getattr(b, k) for b in tpmf.BOUNDS]) for k in ("lo", "hi"))
    assert np.all((r.values[0] >= lo) & (r.values[0] <= hi))
    assert r.train_error[0] < r.start_error[0]          # the defaults are off on this crop (7.6 %)
    err = tfit.hard_errors(pb, r.values, pb.masks(), one, CONFIG.max_window_m)[0]
    assert err + 0.01 * tfit._penalty(r.values, tpmf.TUNER)[0] == pytest.approx(r.train_error[0])


def test_cli_tune_pmf_writes_params_that_filter_reads(tmp_path, capsys):
    laz = tmp_path / "crop.laz"
    gfjax.write(crop_cloud(), laz)
    out = tmp_path / "pmf.json"
    code = cli_main.main(["tune", str(laz), "-o", str(out), "--method", "pmf", "--steps", "2", "--folds", "0"])
    assert code == 0, capsys.readouterr()
    data = json.loads(out.read_text())
    assert data["method"] == "pmf" and set(data["values"]) == {"slope", "initial_distance_m", "max_distance_m"}
    assert data["units"]["max_distance_m"] == "m" and "grid" not in data
    setup = method_setup(argparse.Namespace(params=str(out), method=None, preset=None, set_values=[]))
    assert setup.name == "pmf"
    assert np.float32(setup.params.max_distance_m) == np.float32(data["values"]["max_distance_m"])
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "p.json"), "--method", "pmf",
                          "--windows", "12"]) == 2


def test_cli_tune_pmf_starts_from_and_guards_against_the_values_the_terrain_gives(tmp_path, capsys):
    """PMF's first threshold follows the data (0.5 m, not the fixed 0.15 m): the fit starts
    there, and a fit the guard rejects leaves those values, not the fixed ones."""
    from gfjax import adaptive, pmf
    from gfjax.pmf.config import INITIAL_DISTANCE_M

    laz = tmp_path / "crop.laz"
    cloud = crop_cloud()
    gfjax.write(cloud, laz)
    out = tmp_path / "pmf.json"
    # two folds of a few blocks: too few units for the guard ever to keep a fit (module docstring)
    code = cli_main.main(["tune", str(laz), "-o", str(out), "--method", "pmf", "--steps", "1", "--folds", "2",
                          "--block", "30"])
    assert code == 0, capsys.readouterr()
    data = json.loads(out.read_text())
    xyz = gfjax.read(laz).xyz_m
    expected = pmf.adapt(adaptive.measure(xyz, xyz))
    assert data["start"]["chosen_from_terrain"] == expected
    assert data["start"]["values"]["initial_distance_m"] == INITIAL_DISTANCE_M != float(pmf.Params().initial_distance_m)
    assert not data["validation"]["kept"] and data["fitted"] == []
    for key in ("initial_distance_m", "max_distance_m"):
        assert data["values"][key] == expected[key]
    assert data["values"]["slope"] == data["start"]["values"]["slope"]
