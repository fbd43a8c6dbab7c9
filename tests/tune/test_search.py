"""Tuning by grid search (`gfjax.tune.search`) and MASF's grid (`gfjax.tune.masf`): the choice
and its guard against brute force, and every candidate's labels equal to the plain filter's."""
from __future__ import annotations

import argparse
import dataclasses
import json

import numpy as np
import pytest

import gfjax
from gfjax import dmf, masf
from gfjax.cli import main as cli_main
from gfjax.cli._common import method_setup
from gfjax.tune import dmf as tdmf
from gfjax.tune import masf as tmasf
from gfjax.tune import search
from gfjax.tune.guard import sign_flip_p
from gfjax.tune.problem import Sample, block_folds, block_ids

from .helpers import crop_cloud

SMALL_GRID = {"alpha_max_m": (10.0, 20.0), "alpha_step_m": (2.0, 4.0), "st": (0.05, 0.15), "ft_m": (0.5,)}


def _grid_points(n_side=20, spacing=5.0):
    g = np.arange(n_side) * spacing
    xx, yy = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])


def test_errors_weigh_each_sample_by_its_labelled_points():
    wrong = [np.array([[True, False, False, False], [False, False, False, False]]),
             np.array([[True, True], [True, False]])]
    masks = [np.ones(4, bool), np.array([True, False])]
    err = search.errors(wrong, masks, np.array([0.5, 0.5]))
    np.testing.assert_allclose(err, [0.5 * 0.25 + 0.5 * 1.0, 0.0 + 0.5 * 1.0])


def test_a_candidate_better_in_every_block_is_kept_and_a_tie_keeps_the_defaults():
    xyz = _grid_points()                                         # 400 points, 16 blocks of 25 m
    n = len(xyz)
    rng = np.random.default_rng(0)
    base = rng.random(n) < 0.3
    better = base & (rng.random(n) < 0.5)                        # fixes about half the errors, breaks none
    wrong = [np.stack([base, better, base.copy()])]
    choice = search.validate(wrong, [xyz], [np.ones(n, bool)], default=0, folds=3, block_m=25.0)
    assert choice.kept and choice.index == choice.best == 1
    assert choice.tuned_error < choice.default_error and choice.p_value < 0.05
    tie = search.validate([np.stack([base, base])], [xyz], [np.ones(n, bool)], default=0, folds=3, block_m=25.0)
    assert tie.index == 0 and not tie.kept                       # no gain: the defaults stay


def test_the_guard_equals_a_brute_force_of_its_rule():
    xyz = _grid_points()
    n = len(xyz)
    rng = np.random.default_rng(4)
    wrong = [rng.random((5, n)) < np.linspace(0.2, 0.3, 5)[:, None]]      # noise: nothing truly better
    mask = rng.random(n) < 0.8
    choice = search.validate(wrong, [xyz], [mask], default=2, folds=3, block_m=25.0, seed=7)
    fold = block_folds(xyz, folds=3, block_m=25.0, seed=7)
    unit = block_ids(xyz, block_m=25.0)
    gains = np.zeros(unit.max() + 1)
    for k in range(3):
        train, held = mask & (fold != k), mask & (fold == k)
        err = wrong[0][:, train].mean(axis=1)
        pick = 2 if err[2] <= err.min() else int(np.argmin(err))
        np.add.at(gains, unit[held], (wrong[0][2, held].astype(int) - wrong[0][pick, held]) / mask.sum())
    assert choice.p_value == pytest.approx(sign_flip_p(gains, seed=7))
    assert choice.tuned_error == pytest.approx(wrong[0][2, mask].mean() - gains.sum())
    assert choice.kept == (gains.sum() > 0 and choice.p_value < 0.05 and choice.best != 2)
    unguarded = search.validate(wrong, [xyz], [mask], default=2, folds=0)
    assert unguarded.index == int(np.argmin(wrong[0][:, mask].mean(axis=1))) or not unguarded.kept


def test_candidates_hold_the_defaults_and_every_combination():
    combos, default = tmasf.candidates(masf.Config(), SMALL_GRID)
    assert combos[default] == {"alpha_max_m": 20.0, "alpha_step_m": 2.0, "st": 0.05, "ft_m": 0.5}
    assert len(combos) == 2 * 2 * 2 * 1
    combos, default = tmasf.candidates(masf.Config(), {**SMALL_GRID, "ft_m": (0.7,)})    # the default is added
    assert len(combos) == 16 and combos[default]["ft_m"] == 0.5
    low = tmasf.candidates(masf.Config(), {**SMALL_GRID, "alpha_max_m": (1.0, 20.0)})[0]
    assert all(c["alpha_max_m"] >= masf.Config().min_alpha_m for c in low)          # below alpha_min: left out
    with pytest.raises(ValueError, match="the grid must set"):
        tmasf.candidates(masf.Config(), {"st": (0.1,)})


@pytest.mark.parametrize("far_group", [False, True], ids=["one-group", "far-group"])
def test_every_row_of_the_table_is_the_plain_filters_errors(far_group):
    cloud = crop_cloud()
    if far_group:                                 # a stray group: the filter moves it, so must the table
        xyz = np.vstack([cloud.xyz_m, cloud.xyz_m[:50] + [3000.0, 0.0, 0.0]])
        cloud = gfjax.Cloud.from_xyz(xyz, classification=np.concatenate([cloud.classification,
                                                                          cloud.classification[:50]]))
    sample = Sample.from_cloud(cloud)
    combos, default = tmasf.candidates(masf.Config(), SMALL_GRID)
    wrong = tmasf.METHOD.wrong_table(sample, masf.Config(), combos)
    assert wrong.shape == (len(combos), cloud.n_points)
    for row in sorted({default, 0, len(combos) - 1, 3}):
        c = combos[row]
        config = dataclasses.replace(masf.Config(), alpha_max_m=c["alpha_max_m"], alpha_step_m=c["alpha_step_m"])
        ground = masf.filter(cloud, config=config, params=masf.Params(st=c["st"], ft_m=c["ft_m"])).ground
        np.testing.assert_array_equal(wrong[row], ground != sample.ref_ground)
    assert len({w.tobytes() for w in wrong}) > 1                 # the settings do matter on this crop


DMF_GRID = {"v0": (1.5, 2.0), "max_filter_px": (2,), "rc_min_share": (0.5, 1.0), "height_threshold_m": (0.0, 0.5),
            "height_threshold_w": (0.2,)}


def test_every_row_of_dmfs_table_is_the_plain_filters_errors():
    cloud = crop_cloud()
    sample = Sample.from_cloud(cloud)
    combos, default = tdmf.candidates(dmf.Config(), DMF_GRID)
    assert combos[default] == {"v0": 2.0, "max_filter_px": 2.0, "rc_min_share": 0.5, "height_threshold_m": 0.0,
                               "height_threshold_w": 0.2}
    wrong = tdmf.METHOD.wrong_table(sample, dmf.Config(), combos)
    for row in sorted({default, 0, 5}):
        c = combos[row]
        config = dataclasses.replace(dmf.Config(), v0=c["v0"], max_filter_px=int(c["max_filter_px"]),
                                     rc_min_share=c["rc_min_share"])
        params = dmf.Params(height_threshold_m=c["height_threshold_m"], height_threshold_w=c["height_threshold_w"])
        ground = dmf.filter(cloud, config=config, params=params).ground
        np.testing.assert_array_equal(wrong[row], ground != sample.ref_ground)
    assert len({w.tobytes() for w in wrong}) > 1


def test_dmfs_grid_holds_v1_only_where_the_final_rule_reads_it():
    assert "v1" not in tdmf.candidates(dmf.Config())[0][0]                     # the height rule: v1 has no effect
    combos, default = tdmf.candidates(dataclasses.replace(dmf.Config(), final_rule="both"))
    assert combos[default]["v1"] == 2.0 and {c["v1"] for c in combos} == set(tdmf.V1_VALUES)


def test_cli_tune_masf_writes_params_that_filter_reads(tmp_path, capsys):
    laz = tmp_path / "crop.laz"
    gfjax.write(crop_cloud(), laz)
    out = tmp_path / "masf.json"
    grid = [f"--grid={k}={','.join(str(v) for v in values)}" for k, values in SMALL_GRID.items()]
    assert cli_main.main(["tune", str(laz), "-o", str(out), "--method", "masf", "--folds", "0", *grid]) == 0, \
        capsys.readouterr()
    data = json.loads(out.read_text())
    assert data["method"] == "masf" and set(data["values"]) == {"alpha_max_m", "alpha_step_m", "st", "ft_m"}
    assert data["search"] == "exhaustive grid" and data["grid"]["st"] == [0.05, 0.15]
    assert data["validation"]["tuned"] <= data["validation"]["default"]
    setup = method_setup(argparse.Namespace(params=str(out), method=None, preset=None, set_values=[]))
    assert setup.config.alpha_max_m == data["values"]["alpha_max_m"]              # a Config field
    assert np.float32(setup.params.st) == np.float32(data["values"]["st"])        # a Params field
    sample = Sample.from_cloud(crop_cloud())
    ground = masf.filter(crop_cloud(), config=setup.config, params=setup.params).ground
    assert np.mean((ground != sample.ref_ground)[sample.use]) == pytest.approx(data["validation"]["tuned"])


@pytest.mark.parametrize("args, message", [
    (["--grid", "foo=1"], "--grid foo: unknown key"),
    (["--grid", "st=-1"], "--grid: st must be"),
    (["--grid", "st=1", "--method", "smrf"], "only masf, dmf are tuned on a grid"),
    (["--loss", "kappa"], "--loss kappa: masf is searched on total error only"),
    (["--windows", "12"], "--windows: not a setting of masf"),
    (["--method", "dmf", "--grid", "max_filter_px=1.5"], "--grid: max_filter_px must be an integer"),
    (["--method", "dmf", "--grid", "alpha_max_m=20"], "--grid alpha_max_m: unknown key; dmf searches"),
], ids=["unknown-key", "out-of-range", "not-a-grid-method", "kappa", "windows", "dmf-integer", "dmf-key-of-masf"])
def test_cli_tune_by_grid_refuses_bad_grids_by_name(tmp_path, capsys, args, message):
    laz = tmp_path / "crop.laz"
    gfjax.write(crop_cloud(), laz)
    argv = ["tune", str(laz), "-o", str(tmp_path / "p.json"), *args]
    if "--method" not in args:
        argv += ["--method", "masf"]
    assert cli_main.main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "p.json").exists()


def test_cli_tune_masf_refuses_a_file_without_ground(tmp_path, capsys):
    cloud = crop_cloud()
    laz = tmp_path / "no_ground.laz"
    gfjax.write(gfjax.Cloud.from_xyz(cloud.xyz_m, classification=np.ones(cloud.n_points, np.uint8)), laz)
    assert cli_main.main(["tune", str(laz), "-o", str(tmp_path / "p.json"), "--method", "masf"]) == 2
    assert "no reference ground (class 2)" in capsys.readouterr().err
