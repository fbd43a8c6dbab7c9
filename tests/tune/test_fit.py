"""The optax loop, block validation and the `gfjax tune` command on a small labelled crop."""
from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from gfjax.cli import main as cli_main
from gfjax.cli._common import method_setup
from gfjax.smrf import tuning as tsmrf
from gfjax.tune import fit as tfit
from gfjax.tune.problem import block_folds

from .helpers import WINDOWS, crop_cloud, problem

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

SETTINGS = tfit.Settings(steps=4, eval_every=2, windows_m=WINDOWS)


def test_fit_stays_in_bounds_and_never_worsens_training_error():
    pb = problem(("crop",))
    r = tfit.fit(pb, SETTINGS)
    lo = np.array([b.lo for b in tsmrf.BOUNDS])
    hi = np.array([b.hi for b in tsmrf.BOUNDS])
    assert r.values.shape == (1, 3) and np.all((r.values >= lo) & (r.values <= hi))
    assert r.train_error[0] <= r.start_error[0]
    assert r.window_m[0] in WINDOWS
    assert set(r.history) == set(WINDOWS)
    for h in r.history.values():
        assert h["loss"].shape == (4,) and h["values"].shape == (4, 1, 3) and np.all(np.isfinite(h["loss"]))
        assert np.any(h["values"][-1] != h["values"][0])                    # the parameters moved
    assert r.gradient_calls == 4 * len(WINDOWS)


def test_per_sample_groups_are_independent():
    pb = problem(("flat", "roof", "rough"))
    r = tfit.fit(pb, SETTINGS, group=np.array([0, 1, 2]))
    alone = tfit.fit(pb, SETTINGS, group=np.array([0, 1, 2]), weight=np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(alone.history[WINDOWS[0]]["values"][:, 0], r.history[WINDOWS[0]]["values"][:, 0],
                               rtol=1e-5, atol=1e-6)


def test_block_folds_are_whole_blocks_and_balanced():
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(0, 100, 2000), rng.uniform(0, 100, 2000), np.zeros(2000)])
    fold = block_folds(xyz, folds=3, block_m=25.0, seed=1)
    block = np.floor((xyz[:, :2] - xyz[:, :2].min(axis=0)) / 25.0).astype(int)
    for key in np.unique(block, axis=0):
        assert len(np.unique(fold[np.all(block == key, axis=1)])) == 1
    counts = np.bincount([fold[np.all(block == k, axis=1)][0] for k in np.unique(block, axis=0)])
    assert counts.tolist() == [6, 5, 5]
    np.testing.assert_array_equal(fold, block_folds(xyz, folds=3, block_m=25.0, seed=1))
    with pytest.raises(ValueError):
        block_folds(xyz, folds=1, block_m=25.0)


def test_settings_checks():
    for bad in (dict(steps=0), dict(loss="l2"), dict(prior=-1.0), dict(windows_m=()), dict(eval_every=0)):
        with pytest.raises(ValueError):
            tfit.Settings(**bad)


def test_cli_tune_writes_params_that_filter_reads(tmp_path, capsys):
    import gfjax

    laz = tmp_path / "crop.laz"
    gfjax.write(crop_cloud(), laz)
    out = tmp_path / "params.json"
    code = cli_main.main(["tune", str(laz), "-o", str(out), "--steps", "2", "--folds", "0", "--windows", "18"])
    assert code == 0, capsys.readouterr()
    data = json.loads(out.read_text())
    assert data["method"] == "smrf" and set(data["values"]) == {"slope", "threshold_m", "scalar", "window_m"}
    assert data["units"]["threshold_m"] == "m" and "validation" in data
    for key in data["fitted"]:
        assert key in ("slope", "threshold_m", "scalar")
    setup = method_setup(argparse.Namespace(params=str(out), method=None, preset=None, set_values=[]))
    assert setup.config.window_m == data["values"]["window_m"]                # what `filter --params` uses
    assert np.float32(setup.params.slope) == np.float32(data["values"]["slope"])
    assert data["validation"]["units"] is None                                # --folds 0: no guard
    guarded = tmp_path / "guarded.json"
    code = cli_main.main(["tune", str(laz), "-o", str(guarded), "--steps", "2", "--folds", "2", "--block", "14",
                          "--windows", "18"])
    assert code == 0, capsys.readouterr()
    report = json.loads(guarded.read_text())["validation"]
    assert report["units"] == "blocks of 14 m" and 0 <= report["p_value"] <= 1 and len(report["per_fold"]) == 2
    if not report["kept"]:
        assert json.loads(guarded.read_text())["values"] == {b.name: b.default for b in tsmrf.BOUNDS} | {"window_m": 18.0}
    else:
        assert report["p_value"] < 0.05 and report["tuned"] < report["default"]
    assert cli_main.main(["tune", str(laz), "-o", str(out), "--steps", "2"]) == 2          # exists
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "p.json"), "--method", "sparsegf"]) == 2
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "p.txt")]) == 2
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "q.json"), "--alpha", "1.5"]) == 2


def test_each_methods_tuner_is_found_through_the_registry_and_pickled_by_name():
    import pickle

    import gfjax
    from gfjax.masf import tuning as tmasf
    from gfjax.pmf import tuning as tpmf
    from gfjax.tune import tuners

    assert tuners.get("pmf") is tpmf.TUNER and tuners.get("masf") is tmasf.TUNER
    assert tuners.of_config(gfjax.smrf.Config()) is tsmrf.TUNER
    assert pickle.loads(pickle.dumps(tsmrf.TUNER)) is tsmrf.TUNER
    with pytest.raises(ValueError, match="cannot be tuned; tunable: .*masf"):
        tuners.get("sparsegf")
    with pytest.raises(ValueError, match="no method tuned by gradient has a Config"):
        tuners.of_config(gfjax.masf.Config())
