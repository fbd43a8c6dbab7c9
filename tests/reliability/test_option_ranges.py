"""Option ranges: every numeric option and `--set` key has one documented range, checked
before any file is read (exit 2 naming the option and the range), and the sizes whose
product sets a raster or a loop are checked against the memory budget with an estimate."""
from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401

from gfjax import limits, methods
from gfjax.cli import ranges
from gfjax.errors import InputError, SettingError
from gfjax.io import las as las_io
from gfjax.tiling.tiles import Tiling

REPO = Path(__file__).resolve().parents[2]
METHOD_NAMES = methods.names()


def _numeric_fields(cls) -> list[str]:
    names = []
    for field in dataclasses.fields(cls):
        default = field.default
        if hasattr(default, "shape"):
            default = default.item()
        if isinstance(default, (int, float)) and not isinstance(default, bool) or default is None:
            names.append(field.name)
    return names


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_every_numeric_key_of_every_method_has_a_range(name):
    method = methods.get(name)
    for cls in (method.Config, method.Params):
        if cls is None:
            continue
        missing = [key for key in _numeric_fields(cls) if key not in method.ranges]
        assert missing == [], f"{name}.{cls.__name__}: no range for {missing}"


@pytest.mark.parametrize("name", METHOD_NAMES)
def test_defaults_and_presets_are_in_range(name):
    method = methods.get(name)
    methods.make_config_and_params(method)
    for preset in method.presets:
        methods.make_config_and_params(method, preset=preset)


@pytest.fixture
def scene(tmp_path, monkeypatch) -> Path:
    """A small LAS file; reading its points fails the test (the checks come first)."""
    path = write_scene(tmp_path / "in.las")

    def no_read(*args, **kwargs):
        raise AssertionError("points were read before the options were checked")

    monkeypatch.setattr(las_io, "read", no_read)
    return path


# (method, --set value, the range its message states)
OUT_OF_RANGE = {
    "smrf cell_m zero": ("smrf", "cell_m=0", "cell_m must be > 0 and <= 100 m, got 0.0"),
    "smrf cell_m huge": ("smrf", "cell_m=1e4", "cell_m must be > 0 and <= 100 m, got 10000.0"),
    "smrf window over 1000 cells": ("smrf", "window_m=2000", "window_m must be <= 1000 cell_m"),
    "smrf harmonic iteration cap": ("smrf", "inpaint_max_iter=1000000000",
                                    "inpaint_max_iter must be an integer >= 1 and <= 1e6, got 1000000000"),
    "smrf negative threshold": ("smrf", "threshold_m=-1", "threshold_m must be >= 0 and <= 1000 m, got -1.0"),
    "smrf nan slope": ("smrf", "slope=nan", "slope must be finite and >= 0 and <= 100, got nan"),
    "pmf window base": ("pmf", "base=100", "base must be an integer >= 2 and <= 16, got 100"),
    "csf iteration cap": ("csf", "iterations=1000000000", "iterations must be an integer >= 1 and <= 1e5"),
    "csf time step": ("csf", "time_step=0", "time_step must be > 0 and <= 10, got 0.0"),
    "dmf basal iteration cap": ("dmf", "basal_max_iter=0", "basal_max_iter must be an integer >= 1 and <= 1e5"),
    "dmf voxel size": ("dmf", "voxel_m=-1", "voxel_m must be None or > 0 and <= 100 m, got -1"),
    "dmf cylinder radius": ("dmf", "basal_radius_w=1000", "basal_radius_w must be > 0 and <= 20 W"),
    "masf alpha step": ("masf", "alpha_step_m=0.001", "alpha_step_m must give at most 1000 layers"),
    "masf grid": ("masf", "grid_m=0", "grid_m must be > 0 and <= 100 m, got 0.0"),
    "masf passes": ("masf", "layer_passes=1000", "layer_passes must be an integer >= 1 and <= 100, got 1000"),
    "sparsegf decision threshold": ("sparsegf", "smrf_object_probability=1.5",
                                    "smrf_object_probability must be > 0 and < 1, got 1.5"),
    "sparsegf unknown decision": ("sparsegf", "decision=smrf",
                                  "decision must be one of ('network', 'network+smrf'), got 'smrf'"),
    "sparsegf voxel finer than its keys": ("sparsegf", "voxel_m=0.0001", "voxel_m must be >= 0.05 and < 1e5 m"),
    "sparsegf patch step": ("sparsegf", "step_m=0.001", "step_m must be >= 10 and < 1e5 m, got 0.001"),
}


@pytest.mark.parametrize("case", list(OUT_OF_RANGE), ids=list(OUT_OF_RANGE))
def test_out_of_range_set_value_exits_2_naming_key_and_range(case, scene, tmp_path, capsys):
    method, setting, message = OUT_OF_RANGE[case]
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", method, "--set", setting)
    assert code == 2
    line = error_line(err)
    assert line.startswith("gfjax: error: --set: ") and message in line, line
    assert sorted(os.listdir(tmp_path)) == ["in.las"]


def test_out_of_range_preset_override_names_the_preset(scene, tmp_path, capsys):
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", "smrf",
                           "--params", _params_file(tmp_path, {"slope": 1e9}))
    assert code == 2
    assert f"--params {tmp_path / 'p.json'}: slope must be >= 0 and <= 100" in error_line(err)


def _params_file(tmp_path: Path, values: dict) -> Path:
    import json

    path = tmp_path / "p.json"
    path.write_text(json.dumps({"method": "smrf", "values": values}))
    return path


def test_tile_size_out_of_range_names_the_option(scene, tmp_path, capsys):
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", "smrf",
                           "--tile-size", "1e6")
    assert code == 2
    assert error_line(err) == "gfjax: error: --tile-size: tile_size_m must be > 0 and <= 1e5 m (>= the method's cell), got 1000000.0"


def test_tile_raster_over_the_memory_budget_exits_2_with_the_estimate(scene, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(limits.BUDGET_ENV, "1")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", "smrf",
                           "--set", "cell_m=0.1", "--tile-size", "2000")
    assert code == 2
    line = error_line(err)
    assert line.startswith("gfjax: error: --set, --tile-size: a batch of 1 tile raster(s) of 21,001 x 21,001 cells "
                           "((tile_size_m + 2 buffer_m) / cell_m) needs about ")
    assert line.endswith("GiB, more than the memory budget of 1.0 GiB (set GFJAX_MEMORY_BUDGET_GB to change it)")


# (method, fields set, the error's keys): checks of one field and of fields that must agree
SETTING_ERRORS = [
    ("smrf", {"cell_m": 5.0, "window_m": 1.0}, ("window_m", "cell_m")),
    ("smrf", {"inpaint": "nearest-ish"}, ("inpaint",)),
    ("pmf", {"cell_m": 0.01, "max_window_m": 100.0}, ("max_window_m", "cell_m")),
    ("masf", {"alpha_max_m": 0.01}, ("alpha_max_m",)),
    ("dmf", {"final_rule": "nope"}, ("final_rule",)),
    ("csf", {"slope_smooth": 1}, ("slope_smooth",)),
    ("sparsegf", {"r_in_m": 50.0}, ("r_in_m", "r_oc_m", "r_oo_m")),
    ("smrf", {"cell_m": -1.0}, ("cell_m",)),
]


@pytest.mark.parametrize("name, fields, keys", SETTING_ERRORS, ids=[f"{n} {' '.join(f)}" for n, f, _ in SETTING_ERRORS])
def test_setting_errors_carry_the_keys_concerned(name, fields, keys, unchecked):
    with pytest.raises(SettingError) as caught:
        methods.get(name).Config(**fields)
    assert caught.value.keys == keys
    assert str(caught.value).startswith(keys[0])


def test_an_error_names_the_options_that_gave_its_keys_not_those_that_did_not():
    smrf = methods.get("smrf")
    with pytest.raises(InputError, match=r"^--set, params\.json: window_m must be >= cell_m, got 1\.0$"):
        methods.make_config_and_params(smrf, {"window_m": "1"}, values={"cell_m": 5.0}, values_source="params.json")
    with pytest.raises(InputError, match=r"^--tile-size, --set: tile_size_m must be >= the cell \(1 m\), got 0\.5$"):
        methods.make_config_and_params(smrf, {"cell_m": "1", "threshold_m": "1"}, tiling=Tiling(tile_size_m=0.5),
                                       tiling_sources={"tile_size_m": "--tile-size"})
    with pytest.raises(InputError, match=r"^--set: inpaint must be one of"):       # a key left at its default
        methods.make_config_and_params(smrf, {"inpaint": "bogus"})


def test_smaller_tiles_bring_the_same_cell_within_the_budget(tmp_path, monkeypatch):
    monkeypatch.setenv(limits.BUDGET_ENV, "1")
    smrf = methods.get("smrf")
    with pytest.raises(Exception, match="memory budget"):
        methods.make_config_and_params(smrf, {"cell_m": "0.1"})
    config, _ = methods.make_config_and_params(smrf, {"cell_m": "0.1"}, tiling=Tiling(tile_size_m=50.0, buffer_m=10.0))
    assert config.cell_m == 0.1
    with pytest.raises(InputError, match=r"^--set: tile_size_m is a tiling option, not a setting of method smrf: "
                                         r"give --tile-size / --buffer"):
        methods.make_config_and_params(smrf, {"tile_size_m": "50"})


@pytest.mark.parametrize("method", ["csf", "smrf"])
def test_two_points_far_apart_are_filtered_apart(method, tmp_path, capsys, monkeypatch):
    """Two points 50 km apart are two groups, each filtered alone (`gfjax.tiling.driver`): the
    header's box says nothing of the rasters, so it is not refused before reading."""
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = np.array([0.0, 50_000.0]), np.array([0.0, 50_000.0]), np.array([0.0, 1.0])
    las.write(tmp_path / "far.las")
    monkeypatch.setenv(limits.BUDGET_ENV, "1")
    code, _, err = run_cli(capsys, "filter", tmp_path / "far.las", "-o", tmp_path / "out.las", "--method", method)
    assert code == 0, err
    assert np.array_equal(laspy.read(tmp_path / "out.las").classification, [2, 2])


# The cells are given: left to the rules, a cloud this thin gets cells coarse enough for its
# points (`adaptive.cost_cell_m`) and fits the budget.
@pytest.mark.parametrize("method, cell, what", [("csf", "cell_m=1", "a cloth of 49,9"),
                                                ("masf", "grid_m=1", "a grid of 49,9"),
                                                ("dmf", "voxel_m=1", "the whole-cloud rasters of 49,9"),
                                                ("smrf", "cell_m=6", "the whole-cloud rasters of 8,3"),
                                                ("pmf", "cell_m=6", "the whole-cloud rasters of 8,3")])
def test_one_group_over_the_budget_is_refused_after_reading(method, cell, what, tmp_path, capsys, monkeypatch):
    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    steps = np.arange(0.0, 50_000.0, 50.0)                           # a chain of points 50 m apart
    las.x, las.y, las.z = steps, steps, np.zeros_like(steps)
    las.write(tmp_path / "line.las")
    monkeypatch.setenv(limits.BUDGET_ENV, "1")
    code, _, err = run_cli(capsys, "filter", tmp_path / "line.las", "-o", tmp_path / "out.laz", "--method", method,
                           "--set", cell)
    assert code == 2 and what in error_line(err) and "memory budget of 1.0 GiB" in error_line(err)
    assert sorted(os.listdir(tmp_path)) == ["line.las"]


def test_dtm_command_grid_over_the_budget_exits_2_before_reading(scene, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(limits.BUDGET_ENV, "0.25")
    code, _, err = run_cli(capsys, "dtm", scene, "-o", tmp_path / "d.tif", "--cell", "0.001")
    assert code == 2
    line = error_line(err)
    assert f"{scene}: a DTM of" in line and "use a larger --cell" in line
    assert sorted(os.listdir(tmp_path)) == ["in.las"]


def test_dtm_command_cell_out_of_range(scene, tmp_path, capsys):
    code, _, err = run_cli(capsys, "dtm", scene, "-o", tmp_path / "d.tif", "--cell", "2000")
    assert code == 2 and error_line(err) == "gfjax: error: --cell: cell_m must be > 0 and <= 1000 m, got 2000.0"


def test_bad_memory_budget_setting_exits_2(scene, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv(limits.BUDGET_ENV, "lots")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", "smrf")
    assert code == 2 and "GFJAX_MEMORY_BUDGET_GB='lots': must be a number of GiB > 0" in error_line(err)


def test_the_cli_docs_list_the_generated_table_of_ranges():
    text = (REPO / "docs" / "cli.md").read_text()
    block = re.search(r"<!-- option ranges: generated by .*? -->\n(.*?)\n<!-- end of option ranges -->", text, re.S)
    assert block is not None, "docs/cli.md has no generated table of option ranges"
    assert block.group(1) == ranges.markdown_table(), "docs/cli.md table is stale: regenerate with python -m gfjax.cli.ranges"


def test_range_text_and_checks_agree():
    cell = limits.Range(0, 100, low_open=True, unit="m")
    assert cell.text() == "> 0 and <= 100 m"
    assert [cell.contains(v) for v in (0, 1e-9, 100, 100.5, float("nan"), float("inf"), True, "1")] == \
        [False, True, True, False, False, False, False, False]
    steps = limits.Range(1, 10, integer=True)
    assert steps.contains(3) and not steps.contains(3.0) and not steps.contains(11)
    assert limits.Range(0, None, inf_ok=True).contains(float("inf"))
    with pytest.raises(ValueError, match=r"^cell_m must be > 0 and <= 100 m, got -1$"):
        limits.check_value("cell_m", -1, cell)


COMMAND_OPTIONS = {
    "tune steps": (["tune", "{scene}", "-o", "{dir}/p.json", "--steps", "1000000000"],
                   "--steps: must be an integer >= 1 and <= 1e5, got 1000000000"),
    "tune block": (["tune", "{scene}", "-o", "{dir}/p.json", "--block", "0"], "--block: must be > 0 and <= 1e5 m, got 0"),
    "tune window grid": (["tune", "{scene}", "-o", "{dir}/p.json", "--windows", "12,1e6"],
                         "--windows: window_m must be > 0 and <= 10000 m (>= cell_m, <= 1000 cell_m), got 1000000.0"),
    "tune rigidness grid": (["tune", "{scene}", "-o", "{dir}/p.json", "--method", "csf", "--rigidness", "1,500"],
                            "--rigidness: rigidness must be an integer >= 1 and <= 100, got 500"),
    "train epochs": (["train", "{scene}", "-o", "{dir}/m.eqx", "--epochs", "100000000"],
                     "--epochs: must be an integer >= 1 and <= 10000, got 100000000"),
    "train seed": (["train", "{scene}", "-o", "{dir}/m.eqx", "--seed", "-1"],
                   "--seed: must be an integer >= 0 and <= 4294967295, got -1"),
    "bench timeout": (["bench", "{scene}", "--timeout", "nan"], "--timeout: must be > 0 and <= 1e7 s, got nan"),
    "eval reference class": (["eval", "{scene}", "--reference", "{scene}", "--reference-class", "300"],
                             "--reference-class: must be an integer >= 0 and <= 255, got 300"),
    "dtm ground class": (["dtm", "{scene}", "-o", "{dir}/d.tif", "--ground-class", "-3"],
                         "--ground-class: must be an integer >= 0 and <= 255, got -3"),
}


@pytest.mark.parametrize("case", list(COMMAND_OPTIONS), ids=list(COMMAND_OPTIONS))
def test_out_of_range_command_option_exits_2_naming_the_range(case, scene, tmp_path, capsys):
    argv, message = COMMAND_OPTIONS[case]
    code, _, err = run_cli(capsys, *[a.format(scene=scene, dir=tmp_path) for a in argv])
    assert code == 2
    assert error_line(err) == f"gfjax: error: {message}"
    assert sorted(os.listdir(tmp_path)) == ["in.las"]


def test_python_api_filter_checks_the_budget_for_the_cloud_it_is_given(monkeypatch):
    from gfjax import smrf
    from gfjax.errors import InputError
    from gfjax.io.cloud import Cloud

    monkeypatch.setenv(limits.BUDGET_ENV, "1")
    steps = np.arange(0.0, 200_000.0, 50.0)                          # one group: a chain 50 m apart
    cloud = Cloud.from_xyz(np.column_stack([steps, steps, np.zeros_like(steps)]))
    with pytest.raises(InputError, match=r"the whole-cloud rasters of 199,9\d\d x 199,9\d\d cells .* memory budget"):
        smrf.filter(cloud, config=smrf.Config())            # 1 m cells as given (the spacing would coarsen them)


def test_batch_estimate_counts_the_tiles_the_extent_holds():
    smrf = methods.get("smrf")
    config, _ = methods.make_config_and_params(smrf)
    one = config.memory_estimates()[0]
    four = config.memory_estimates((900.0, 900.0))[0]            # 2 x 2 tiles of 500 m
    many = config.memory_estimates((10_000.0, 10_000.0))[0]       # 400 tiles: batches of 8
    assert "a batch of 1 tile" in one.what and "a batch of 4 tile" in four.what and "a batch of 8 tile" in many.what
    assert four.n_bytes == 4 * one.n_bytes and many.n_bytes == 8 * one.n_bytes


def test_a_set_value_beyond_float32_is_refused_by_its_range_not_as_inf(scene, tmp_path, capsys):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")                   # no overflow warning on the way
        code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--method", "smrf",
                               "--set", "slope=1e308")
    assert code == 2 and error_line(err) == "gfjax: error: --set: slope must be >= 0 and <= 100, got 1e+308"


def test_max_edge_takes_inf_as_its_range_says_and_refuses_nan(scene, tmp_path, capsys):
    code, _, err = run_cli(capsys, "dtm", scene, "-o", tmp_path / "d.tif", "--max-edge", "nan")
    assert code == 2 and error_line(err) == "gfjax: error: --max-edge: expected a number, got 'nan'"
    code, _, err = run_cli(capsys, "dtm", scene, "-o", tmp_path / "d.tif", "--max-edge", "-1")
    assert code == 2 and "--max-edge: max_edge_m must be >= 0 m, or inf, got -1.0" in error_line(err)
    from gfjax.dtm.build import check_options

    assert check_options("", cell_m=1.0, max_edge_m=float("inf")) == (1.0, float("inf"))


def test_a_scheduler_port_outside_tcp_is_refused_at_once(scene, tmp_path, capsys):
    pytest.importorskip("distributed")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.laz", "--scheduler", "tcp://127.0.0.1:99999")
    assert code == 2 and "port 99999 is not a TCP port (1-65535)" in error_line(err)
