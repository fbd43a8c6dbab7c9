"""`gfjax info`, `gfjax dtm`, `gfjax eval`, and the dispatch of `main`."""
from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import laspy
import numpy as np
import pyproj
import pytest
from cli_helpers import SCENE_CLASSES, error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401
from conftest import shared_file

from gfjax import methods
from gfjax.cli import eval as eval_cli
from gfjax.cli import info as info_cli
from gfjax.cli import main as cli_main
from gfjax.data import demo_sample
from gfjax.io import las as las_io

# ---------------------------------------------------------------- info


def test_info_summary_of_a_scene(tmp_path, capsys):
    src = write_scene(tmp_path / "in.laz")
    summary = info_cli.summarize(las_io.read(src))
    assert (summary["version"], summary["point_format"], summary["point_count"]) == ("1.4", 6, 8)
    assert summary["epsg"] == 32632 and summary["horizontal_unit_m"] == 1.0
    counts = {int(code): entry["count"] for code, entry in summary["classes"].items()}
    assert counts == {int(c): int(k) for c, k in zip(*np.unique(SCENE_CLASSES, return_counts=True))}
    assert summary["classes"]["2"]["name"] == "ground" and summary["ignored_points"] == 1
    code, out, err = run_cli(capsys, "info", src)
    assert code == 0, err
    assert "LAS 1.4, point format 6 (LAZ), 8 points" in out
    assert "WGS 84 / UTM zone 32N (EPSG:32632)" in out
    assert "2  ground" in out and "7  low point (noise)" in out


def test_info_says_metres_are_assumed_without_crs(tmp_path, capsys):
    src = write_scene(tmp_path / "nocrs.las", crs=None)
    code, out, _ = run_cli(capsys, "info", src)
    assert code == 0
    assert "CRS         none" in out and "no CRS in file: metres assumed" in out


def test_info_json_of_several_files(tmp_path, capsys):
    for name in ("a.laz", "b.laz"):
        write_scene(tmp_path / name)
    code, out, _ = run_cli(capsys, "info", tmp_path, "--json", "--units", "us-ft")
    assert code == 0
    summaries = json.loads(out)
    assert [os.path.basename(s["path"]) for s in summaries] == ["a.laz", "b.laz"]
    assert summaries[0]["vertical_unit_m"] == 1200 / 3937


def test_info_describes_a_file_in_degrees(tmp_path, capsys):
    src = write_scene(tmp_path / "geo.laz", crs=pyproj.CRS.from_epsg(4326))
    code, out, err = run_cli(capsys, "info", src)
    assert code == 0, err
    assert "CRS         WGS 84 (EPSG:4326)" in out and "8 points" in out and "2  ground" in out
    assert "units       none usable: the CRS 'WGS 84' is geographic (degrees)" in out
    code, out, err = run_cli(capsys, "info", src, "--json")
    assert code == 0, err
    summary = json.loads(out)
    assert (summary["epsg"], summary["horizontal_unit_m"], summary["vertical_unit_m"]) == (4326, None, None)
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz")        # filtering needs metres
    assert code == 2 and "is geographic (degrees)" in error_line(err)


@pytest.mark.parametrize("name", ["empty.las", "empty.laz"])
def test_info_describes_a_file_without_points(tmp_path, capsys, name):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_crs(pyproj.CRS.from_epsg(32632))
    laspy.LasData(header).write(tmp_path / name)
    code, out, err = run_cli(capsys, "info", tmp_path / name)
    assert code == 0, err
    assert ", 0 points" in out and "WGS 84 / UTM zone 32N (EPSG:32632)" in out and "none (no points)" in out
    code, _, err = run_cli(capsys, "dtm", tmp_path / name, "-o", tmp_path / "d.tif")    # a DTM needs points
    assert code == 2 and "the file holds no points" in error_line(err)


@pytest.mark.data
def test_info_autzen_feet(capsys):
    code, out, _ = run_cli(capsys, "info", shared_file("pdal_autzen/autzen_trim.laz"))
    assert code == 0
    assert "horizontal international foot (0.3048 m), vertical international foot (0.3048 m)" in out
    assert "110,000 points" in out


# ---------------------------------------------------------------- dtm


def test_dtm_of_isprs_sample_has_epsg_32632(tmp_path, capsys):
    pytest.importorskip("gfjax.dtm")
    rasterio = pytest.importorskip("rasterio")
    code, out, err = run_cli(capsys, "dtm", demo_sample(), "-o", tmp_path / "dtm.tif", "--cell", "1",
                             "--hillshade", tmp_path / "hs.png")
    assert code == 0, err
    with rasterio.open(tmp_path / "dtm.tif") as dtm:
        assert dtm.crs.to_epsg() == 32632 and dtm.res == (1.0, 1.0) and dtm.nodata == -9999
    assert (tmp_path / "hs.png").stat().st_size > 0
    assert sorted(os.listdir(tmp_path)) == ["dtm.tif", "hs.png"]


def test_dtm_surface_chm_writes_heights_over_the_dtm_lattice(tmp_path, capsys):
    pytest.importorskip("gfjax.dtm")
    rasterio = pytest.importorskip("rasterio")
    for surface in ("ground", "chm"):
        code, _, err = run_cli(capsys, "dtm", demo_sample(), "-o", tmp_path / f"{surface}.tif", "--surface", surface)
        assert code == 0, err
    with rasterio.open(tmp_path / "ground.tif") as dtm, rasterio.open(tmp_path / "chm.tif") as chm:
        assert chm.transform == dtm.transform and chm.crs == dtm.crs
        heights = chm.read(1, masked=True)
        assert heights.min() >= 0.0 and 5.0 < heights.max() < 60.0       # samp12: houses and trees


def test_dtm_without_ground_points(tmp_path, capsys):
    pytest.importorskip("gfjax.dtm")
    src = write_scene(tmp_path / "in.laz")
    code, _, err = run_cli(capsys, "dtm", src, "-o", tmp_path / "d.tif", "--ground-class", "9")
    assert code == 2 and "no ground points" in error_line(err)
    assert sorted(os.listdir(tmp_path)) == ["in.laz"]


# ---------------------------------------------------------------- eval


def _relabelled(src, path, classes, order=None):
    las = laspy.read(src)
    las.classification = classes
    if order is not None:
        las.points = las.points[order]
    las.write(path)
    return path


def test_eval_against_reference_in_same_and_shuffled_order(tmp_path, capsys):
    ref = write_scene(tmp_path / "ref.laz")
    pred_classes = SCENE_CLASSES.copy()
    pred_classes[[0, 3]] = [1, 2]  # one ground missed (fn), one vegetation taken as ground (fp)
    same = _relabelled(ref, tmp_path / "same.laz", pred_classes)
    shuffled = _relabelled(ref, tmp_path / "shuffled.laz", pred_classes, order=np.arange(8)[::-1].copy())
    code, out, err = run_cli(capsys, "eval", same, shuffled, "--reference", ref, ref,
                             "--json", tmp_path / "m.json")
    assert code == 0, err
    assert "shuffled.laz: point order differs: matched on exact scaled integer XYZ" in out
    document = json.loads((tmp_path / "m.json").read_text())
    for record in document["files"]:
        m = record["metrics"]
        # 7 scored points (the noise point is not scored); reference ground: 0, 1, 5
        assert (m["tp"], m["fp"], m["fn"], m["tn"], m["n_points"]) == (2, 1, 1, 3, 7)
        assert m["total_error"] == pytest.approx(2 / 7)
    assert document["mean"]["total_error"] == pytest.approx(2 / 7)
    assert "mean (unweighted)" in out


def test_eval_runs_a_method_against_own_labels(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz")
    code, out, err = run_cli(capsys, "eval", src, "--method", "fake", "--reference-class", "2")
    assert code == 0, err
    assert "scored method fake against their own labels" in out
    # fake ground 0, 1, 2, 7 vs reference ground 0, 1, 5: tp 2, fp 2, fn 1, tn 2 (noise unscored)
    row = [line for line in out.splitlines() if line.startswith("in.laz")][0]
    assert "57.14%" in row and "42.86%" in row  # OA 4/7, total error 3/7


def test_match_points_refuses_other_points(tmp_path):
    ref = las_io.read(write_scene(tmp_path / "ref.laz"))
    las = laspy.read(tmp_path / "ref.laz")
    las.z = las.z + 0.01
    las.write(tmp_path / "moved.laz")
    with pytest.raises(las_io.InputError, match="not the same XYZ positions"):
        eval_cli.match_points(las_io.read(tmp_path / "moved.laz"), ref)
    index, note = eval_cli.match_points(ref, ref)
    assert index is None and note == "same point order"


# ---------------------------------------------------------------- dispatch


def test_help_lists_present_commands_and_version(capsys):
    code, out, _ = run_cli(capsys, "--help")
    assert code == 0
    for name in ("info", "filter", "dtm", "eval", "demo"):
        assert name in out
    code, out, _ = run_cli(capsys, "--version")
    assert code == 0 and out.startswith("gfjax ")


def test_missing_subcommand_module(capsys, monkeypatch):
    monkeypatch.setitem(cli_main.SUBCOMMANDS, "ghost", "a command whose module is not installed")
    monkeypatch.setattr(cli_main, "ALWAYS_LISTED", ("demo", "ghost"))
    code, _, err = run_cli(capsys, "ghost")
    assert code == 2 and error_line(err) == "gfjax: error: ghost: not available in this build"
    monkeypatch.setattr(cli_main, "ALWAYS_LISTED", ())
    code, out, _ = run_cli(capsys, "--help")
    assert code == 0 and "ghost" not in out


def test_only_the_requested_command_is_imported(monkeypatch):
    imported = []
    real = cli_main._import_command
    monkeypatch.setattr(cli_main, "_import_command", lambda name: imported.append(name) or real(name))
    parser, module = cli_main.build_parser(["--debug", "info", "x.laz"])
    assert imported == ["info"] and module.__name__ == "gfjax.cli.info"
    assert parser.parse_args(["info", "x.laz", "--debug"]).debug is True


# ---------------------------------------------------------------- a closed output pipe


class _ClosedPipe(io.TextIOBase):
    """A standard output whose reader has gone: every write raises, as on a closed pipe."""

    def write(self, text: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")


@pytest.mark.parametrize("command", ["info", "filter", "dtm", "eval"])
def test_a_closed_output_ends_every_command_quietly(tmp_path, capsys, monkeypatch, fake_methods, command):
    src = write_scene(tmp_path / "in.laz")
    argv = {"info": ["info", src], "filter": ["filter", src, "-o", tmp_path / "out.laz", "--method", "fake"],
            "dtm": ["dtm", src, "-o", tmp_path / "d.tif"], "eval": ["eval", src, "--reference", src]}[command]
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    code = cli_main.main([str(a) for a in argv])
    assert (code, capsys.readouterr().err) == (141, "")


def test_a_command_that_compiles_says_so_once_naming_the_method(capsys):
    from gfjax.aot import calls

    with cli_main._talk(quiet=False, method="pmf"):
        calls._state["on_compile"]("gfjax.raster.morphology") # a shared kernel: the command's method
        calls._state["on_compile"]("gfjax.smrf.stages")
    err = capsys.readouterr().err
    assert err.count("compiling") == 1
    assert "gfjax: compiling pmf for a new input shape (kept, so later runs of this shape start at once)" in err
    assert calls._state["on_compile"] is None


def test_quiet_turns_off_progress_bars_and_compile_notices(monkeypatch):
    from gfjax.aot import calls

    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    with cli_main._talk(quiet=True, method="smrf"):
        assert os.environ["TQDM_DISABLE"] == "1" and calls._state.get("on_compile") is None
    assert "TQDM_DISABLE" not in os.environ
    args = cli_main.build_parser(["filter", "a.laz", "-o", "b.laz", "-q"])[0].parse_args(
        ["filter", "a.laz", "-o", "b.laz", "-q"])
    assert args.quiet and cli_main._method_of(args) == methods.DEFAULT_METHOD


def test_quiet_run_prints_no_progress_bar(tmp_path):
    scene = write_scene(tmp_path / "a.las")
    env = {**os.environ, "GFJAX_EXPORT_CACHE": "0"}
    out = subprocess.run([sys.executable, "-c", "from gfjax.cli.main import main; main()", "filter", str(scene), "-o", str(tmp_path / "b.las"),
                          "--method", "pmf", "--quiet"], capture_output=True, text=True, env=env, check=True)
    assert out.stderr.strip() == "" and "b.las" in out.stdout


def test_csf_run_shows_its_cloth_bar_unless_quiet(tmp_path):
    """CSF's cloth has a bar like the other methods' stages (on stderr; `-q`: none), which
    says at which step the cloth settled; the labels do not depend on it."""
    scene = write_scene(tmp_path / "a.las")
    env = {k: v for k, v in os.environ.items() if k not in ("GFJAX_EXPORT_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    env.update(GFJAX_CACHE="1", XDG_CACHE_HOME=str(tmp_path / "cache"))       # the quiet run loads the programs
    command = [sys.executable, "-c", "from gfjax.cli.main import main; main()", "filter", str(scene), "--method", "csf"]
    shown = subprocess.run([*command, "-o", str(tmp_path / "b.las")], capture_output=True, text=True, env=env,
                           check=True)
    quiet = subprocess.run([*command, "-o", str(tmp_path / "c.las"), "-q"], capture_output=True, text=True, env=env,
                           check=True)
    assert "csf cloth" in shown.stderr and "settled at step" in shown.stderr
    assert quiet.stderr.strip() == ""
    np.testing.assert_array_equal(laspy.read(tmp_path / "b.las").classification,
                                  laspy.read(tmp_path / "c.las").classification)
