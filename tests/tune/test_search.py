"""Tuning by grid search (`gfjax.tune.search`) and MASF's grid (`gfjax.masf.tuning`): the choice
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
from gfjax.dmf import tuning as tdmf
from gfjax.masf import tuning as tmasf
from gfjax.tune import search
from gfjax.tune.guard import sign_flip_p
from gfjax.tune.problem import Sample, block_folds, block_ids

from .helpers import crop_cloud

SMALL_GRID = {"alpha_max_m": (10.0, 20.0), "alpha_step_m": (2.0, 4.0), "alpha_top_m": (tmasf.NO_TOP, 40.0),
              "st": (0.05, 0.15), "ft_m": (0.5,)}


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


def _one_se_brute(unit_err, default, distance, margin=search.TIE_MARGIN):
    """The one-standard-error rule written out candidate by candidate."""
    total = unit_err.sum(axis=1)
    best = default if total[default] <= total.min() else int(np.argmin(total))
    u = unit_err.shape[1]
    near = []
    for c in range(len(total)):
        d = unit_err[c] - unit_err[best]
        se = np.sqrt(u / (u - 1) * np.sum((d - d.mean()) ** 2)) if u > 1 else 0.0
        if d.sum() <= se + margin + 1e-12:
            near.append(c)
    pick = min(near, key=lambda c: (distance[c], total[c], c))
    return default if total[default] <= total[pick] else pick


def test_unit_errors_split_errors_by_unit():
    rng = np.random.default_rng(3)
    wrong = [rng.random((70, 30)) < 0.3, rng.random((70, 12)) < 0.5]          # more candidates than a chunk
    masks = [rng.random(30) < 0.7, np.ones(12, bool)]
    unit_id = [rng.integers(0, 5, 30), np.full(12, 5)]
    weight = np.array([0.3, 0.7])
    per_unit, present = search.unit_errors(wrong, masks, weight, unit_id, 7)
    brute = np.zeros((70, 7))
    for w, m, u, s in zip(wrong, masks, unit_id, weight):
        for c in range(70):
            np.add.at(brute[c], u[m], s * w[c, m] / m.sum())
    np.testing.assert_allclose(per_unit, brute)
    np.testing.assert_allclose(per_unit.sum(axis=1), search.errors(wrong, masks, weight))
    assert present.tolist() == [True] * 6 + [False]


@pytest.mark.parametrize("seed", range(6))
def test_the_one_se_rule_equals_a_brute_force(seed):
    rng = np.random.default_rng(seed)
    unit_err = rng.random((12, 5)) * 0.1
    unit_err[3] = unit_err[0] - 0.001                                          # a near twin of the defaults
    distance = rng.integers(0, 4, 12)
    distance[0] = 0
    for margin in (0.0, search.TIE_MARGIN, 0.02):
        assert (search.one_se_choice(unit_err, 0, distance, margin=margin)
                == _one_se_brute(unit_err, 0, distance, margin))


def test_the_one_se_rule_prefers_a_near_best_candidate_closer_to_the_defaults():
    unit_err = np.array([[0.30, 0.30, 0.30, 0.30],      # defaults
                         [0.10, 0.30, 0.10, 0.30],      # best on the total, but unsteady across units
                         [0.22, 0.20, 0.21, 0.21]])     # a little worse, steady, one step from the defaults
    assert search.one_se_choice(unit_err, 0, np.array([0, 3, 1])) == 2
    assert search.one_se_choice(unit_err, 0, np.array([0, 1, 1])) == 1       # as near: the lower error
    assert search.one_se_choice(unit_err[:, :1], 0, np.array([0, 3, 1])) == 1   # one unit: no spread, the lowest


def test_a_steady_lead_below_the_margin_is_a_tie():
    """A candidate far from the defaults that beats a near one by less than the margin in every
    unit alike (no spread, so no standard error) does not win: the near one does."""
    unit_err = np.array([[0.020, 0.020, 0.020],          # defaults
                         [0.0010, 0.0010, 0.0010],       # lowest, five grid steps away
                         [0.0013, 0.0013, 0.0013]])      # 0.09 points more in all, one step away
    distance = np.array([0, 5, 1])
    assert search.one_se_choice(unit_err, 0, distance) == 2
    assert search.one_se_choice(unit_err, 0, distance, margin=0.0) == 1


def test_grid_distance_counts_steps_on_each_axis():
    combos, default = search.grid_candidates({"a": 1.0, "b": 0.5}, {"a": (0.0, 1.0, 2.0, 3.0), "b": (0.5, 0.7)})
    distance = search.grid_distance(combos, default)
    assert distance[default] == 0
    assert {(c["a"], c["b"]): int(d) for c, d in zip(combos, distance)}[(3.0, 0.7)] == 2 + 1


def test_the_guard_equals_a_brute_force_of_its_rule():
    xyz = _grid_points()
    n = len(xyz)
    rng = np.random.default_rng(4)
    wrong = [rng.random((5, n)) < np.linspace(0.2, 0.3, 5)[:, None]]      # noise: nothing truly better
    mask = rng.random(n) < 0.8
    distance = np.array([2, 1, 0, 1, 2])
    choice = search.validate(wrong, [xyz], [mask], default=2, distance=distance, folds=3, block_m=25.0, seed=7)
    fold = block_folds(xyz, folds=3, block_m=25.0, seed=7)
    unit = block_ids(xyz, block_m=25.0)

    def rule(m):
        units = np.unique(unit[m])
        per_unit = np.stack([[wrong[0][c, m & (unit == u)].sum() / m.sum() for u in units] for c in range(5)])
        return _one_se_brute(per_unit, 2, distance)

    gains = np.zeros(unit.max() + 1)
    for k in range(3):
        train, held = mask & (fold != k), mask & (fold == k)
        pick = rule(train)
        np.add.at(gains, unit[held], (wrong[0][2, held].astype(int) - wrong[0][pick, held]) / mask.sum())
    assert choice.p_value == pytest.approx(sign_flip_p(gains, seed=7))
    assert choice.tuned_error == pytest.approx(wrong[0][2, mask].mean() - gains.sum())
    pick = rule(mask)
    assert choice.kept == (gains.sum() > 0 and choice.p_value < 0.05 and pick != 2)
    assert choice.index == (pick if choice.kept else 2)
    unguarded = search.validate(wrong, [xyz], [mask], default=2, folds=0)
    assert unguarded.index == int(np.argmin(wrong[0][:, mask].mean(axis=1))) or not unguarded.kept


def test_candidates_hold_the_defaults_and_every_combination():
    base = masf.Config(alpha_max_m=20.0)                     # the given config's values are the defaults
    combos, default = tmasf.candidates(base, SMALL_GRID)
    assert combos[default] == {"alpha_max_m": 20.0, "alpha_step_m": 2.0, "alpha_top_m": tmasf.NO_TOP, "st": 0.05,
                               "ft_m": 0.5}
    assert len(combos) == 2 * 2 * 2 * 2 * 1
    combos, default = tmasf.candidates(base, {**SMALL_GRID, "ft_m": (0.7,)})    # the default is added
    assert len(combos) == 32 and combos[default]["ft_m"] == 0.5
    combos = tmasf.candidates(base, {**SMALL_GRID, "alpha_top_m": (tmasf.NO_TOP, 15.0)})[0]
    assert {(c["alpha_max_m"], c["alpha_top_m"]) for c in combos} == {(10.0, 0.0), (10.0, 15.0), (20.0, 0.0)}
    low = tmasf.candidates(base, {**SMALL_GRID, "alpha_max_m": (1.0, 20.0)})[0]
    assert all(c["alpha_max_m"] >= base.min_alpha_m for c in low)          # below alpha_min: left out
    with pytest.raises(ValueError, match="the grid must set"):
        tmasf.candidates(base, {"st": (0.1,)})


@pytest.mark.parametrize("far_group", [False, True], ids=["one-group", "far-group"])
def test_every_row_of_the_table_is_the_plain_filters_errors(far_group):
    cloud = crop_cloud()
    if far_group:                                 # a stray group: the filter moves it, so must the table
        xyz = np.vstack([cloud.xyz_m, cloud.xyz_m[:50] + [3000.0, 0.0, 0.0]])
        cloud = gfjax.Cloud.from_xyz(xyz, classification=np.concatenate([cloud.classification,
                                                                          cloud.classification[:50]]))
    sample = Sample.from_cloud(cloud)
    combos, default = tmasf.candidates(masf.Config(), SMALL_GRID)
    wrong = tmasf.TUNER.wrong_table(sample, masf.Config(), combos)
    assert wrong.shape == (len(combos), cloud.n_points)
    for row in sorted({default, 0, len(combos) - 1, 3, 5}):
        c = combos[row]
        top = None if c["alpha_top_m"] == tmasf.NO_TOP else c["alpha_top_m"]
        config = dataclasses.replace(masf.Config(), alpha_max_m=c["alpha_max_m"], alpha_step_m=c["alpha_step_m"],
                                     alpha_top_m=top)
        ground = masf.filter(cloud, config=config, params=masf.Params(st=c["st"], ft_m=c["ft_m"])).ground
        np.testing.assert_array_equal(wrong[row], ground != sample.ref_ground)
    assert len({w.tobytes() for w in wrong}) > 1                 # the settings do matter on this crop


DMF_GRID = {"v0": (1.5, 2.0), "max_filter_px": (2,), "rc_min_share": (0.5, 1.0), "height_threshold_m": (0.0, 0.5),
            "height_threshold_w": (0.15,)}


def test_params_values_leave_out_an_absent_top_layer():
    combo = {"alpha_max_m": 20.0, "alpha_step_m": 2.0, "alpha_top_m": tmasf.NO_TOP, "st": 0.05, "ft_m": 0.5}
    assert "alpha_top_m" not in tmasf.values(combo)
    assert tmasf.values({**combo, "alpha_top_m": 90.0})["alpha_top_m"] == 90.0
    assert masf.Config(alpha_top_m=90.0).reach_m == 180.0 and masf.Config().reach_m == 50.0


def test_every_row_of_dmfs_table_is_the_plain_filters_errors():
    cloud = crop_cloud()
    sample = Sample.from_cloud(cloud)
    combos, default = tdmf.candidates(dmf.Config(), DMF_GRID)
    assert combos[default] == {"v0": 2.0, "max_filter_px": 2.0, "rc_min_share": 0.5, "height_threshold_m": 0.0,
                               "height_threshold_w": 0.15}
    wrong = tdmf.TUNER.wrong_table(sample, dmf.Config(), combos)
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
    assert data["method"] == "masf" and {"alpha_max_m", "alpha_step_m", "st", "ft_m"} <= set(data["values"])
    assert data["values"].get("alpha_top_m", 40.0) == 40.0                  # no top layer: the key is left out
    assert data["grid"]["alpha_top_m"] == [0.0, 40.0]
    assert data["search"] == "exhaustive grid" and data["grid"]["st"] == [0.05, 0.15]
    assert data["validation"]["tuned"] <= data["validation"]["default"]
    setup = method_setup(argparse.Namespace(params=str(out), method=None, preset=None, set_values=[]))
    assert setup.config.alpha_max_m == data["values"]["alpha_max_m"]              # a Config field
    assert setup.config.alpha_top_m == data["values"].get("alpha_top_m")
    assert np.float32(setup.params.st) == np.float32(data["values"]["st"])        # a Params field
    sample = Sample.from_cloud(crop_cloud())
    ground = masf.filter(crop_cloud(), config=setup.config, params=setup.params).ground
    assert np.mean((ground != sample.ref_ground)[sample.use]) == pytest.approx(data["validation"]["tuned"])


@pytest.mark.parametrize("args, message", [
    (["--grid", "foo=1"], "--grid foo: unknown key"),
    (["--grid", "st=-1"], "--grid: st must be"),
    (["--grid", "alpha_top_m=-1"], "--grid: alpha_top_m must be"),
    (["--grid", "st=1", "--method", "smrf"], "only dmf, masf are tuned on a grid"),
    (["--loss", "kappa"], "--loss kappa: masf is searched on total error only"),
    (["--windows", "12"], "--windows: not a setting of masf's tuning grid"),
    (["--method", "dmf", "--grid", "max_filter_px=1.5"], "--grid: max_filter_px must be an integer"),
    (["--method", "dmf", "--grid", "alpha_max_m=20"], "--grid alpha_max_m: unknown key; dmf searches"),
], ids=["unknown-key", "out-of-range", "top-out-of-range", "not-a-grid-method", "kappa", "windows", "dmf-integer", "dmf-key-of-masf"])
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
