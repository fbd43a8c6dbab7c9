"""`gfjax filter` with a fake method: classes written, options passed, several inputs, DTM."""
from __future__ import annotations

import json
import os

import laspy
import numpy as np
import pytest
from cli_helpers import SCENE_CLASSES, error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401

from gfjax import methods

# Fake rule: ground iff z <= min z of used points + threshold_m; point 6 (class 7) is ignored.
# Default threshold 0.5 m: points 0, 1, 2, 7 (z 0, 0.1, 0.2, 0.3) are ground.
GROUND_DEFAULT = np.array([1, 1, 1, 0, 0, 0, 0, 1], dtype=bool)


def _classes(path) -> np.ndarray:
    return np.asarray(laspy.read(path).classification)


def test_classes_written_per_spec(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz")
    code, out, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake")
    assert code == 0, err
    assert "in.laz -> " in out and "4 ground of 8 points" in out
    expected = SCENE_CLASSES.copy()
    expected[GROUND_DEFAULT] = 2
    expected[5] = 1                    # was ground (2), now non-ground -> 1
    np.testing.assert_array_equal(_classes(tmp_path / "out.laz"), expected)  # 3, 6, 7 keep theirs
    before, after = laspy.read(src), laspy.read(tmp_path / "out.laz")
    for name in before.point_format.dimension_names:
        if name != "classification":
            np.testing.assert_array_equal(np.asarray(after[name]), np.asarray(before[name]), err_msg=name)


def test_reset_nonground(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.las", "--method", "fake",
                           "--reset-nonground")
    assert code == 0, err
    expected = np.where(GROUND_DEFAULT, 2, 1).astype(np.uint8)
    expected[6] = 7                    # noise keeps its class
    np.testing.assert_array_equal(_classes(tmp_path / "out.las"), expected)


def test_set_preset_and_params_file_precedence(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz")
    fake = fake_methods["fake"]
    params = tmp_path / "params.json"
    params.write_text(json.dumps({"method": "fake", "gfjax_version": "0.1.0", "units": "m",
                                  "values": {"threshold_m": 3.5}}))
    cases = [([], 0.5), (["--preset", "generous"], 100.0), (["--params", params], 3.5),
             (["--preset", "generous", "--params", params], 3.5),
             (["--params", params, "--set", "threshold_m=0.05"], 0.05),
             (["--set", "threshold_m=1", "--set", "cell_m=0.25"], 1.0)]
    for i, (options, threshold) in enumerate(cases):
        code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / f"out{i}.laz", "--method", "fake", *options)
        assert code == 0, (options, err)
        assert fake.calls[-1]["params"].threshold_m == threshold
    assert fake.calls[-1]["config"].cell_m == 0.25
    # --params alone picks its method
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "p.laz", "--params", params)
    assert code == 0, err
    assert fake.calls[-1]["params"].threshold_m == 3.5


def test_default_method_is_the_constant(tmp_path, capsys, fake_methods, monkeypatch):
    monkeypatch.setattr(methods, "DEFAULT_METHOD", "fake")
    src = write_scene(tmp_path / "in.laz")
    code, out, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz")
    assert code == 0, err
    assert ": fake, " in out and len(fake_methods["fake"].calls) == 1


def test_tiling_returns_and_units_reach_the_method(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz", returns=np.array([1, 2, 2, 1, 1, 2, 2, 2], np.uint8))
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake",
                           "--tile-size", "250", "--buffer", "20", "--returns", "last", "--units", "ft")
    assert code == 0, err
    call = fake_methods["fake"].calls[-1]
    assert (call["tiling"].tile_size_m, call["tiling"].buffer_m, call["returns"]) == (250.0, 20.0, "last")
    assert call["cloud"].horizontal_unit_m == 0.3048
    # first returns (0, 3, 4) are not filtered and keep their classes
    classes = _classes(tmp_path / "out.laz")
    np.testing.assert_array_equal(classes[[0, 3, 4]], SCENE_CLASSES[[0, 3, 4]])
    assert classes[1] == 2 and classes[5] == 1


def test_several_inputs_write_one_output_each(tmp_path, capsys, fake_methods):
    (tmp_path / "in").mkdir()
    (tmp_path / "out").mkdir()
    for name in ("a.laz", "b.las"):
        write_scene(tmp_path / "in" / name)
    code, out, err = run_cli(capsys, "filter", str(tmp_path / "in" / "*.la?"), "-o", tmp_path / "out",
                             "--method", "fake", "--independent")     # the same scene twice: no survey
    assert code == 0, err
    assert sorted(os.listdir(tmp_path / "out")) == ["a.laz", "b.las"]
    with laspy.open(tmp_path / "out" / "a.laz") as a, laspy.open(tmp_path / "out" / "b.las") as b:
        assert a.header.are_points_compressed and not b.header.are_points_compressed


def test_several_inputs_need_an_existing_folder(tmp_path, capsys, fake_methods):
    for name in ("a.laz", "b.laz"):
        write_scene(tmp_path / name)
    code, _, err = run_cli(capsys, "filter", tmp_path / "a.laz", tmp_path / "b.laz", "-o", tmp_path / "new",
                           "--method", "fake")
    assert code == 2
    assert "2 inputs need an existing output folder" in error_line(err)
    assert not (tmp_path / "new").exists() and fake_methods["fake"].calls == []


def test_same_name_in_two_folders_is_refused(tmp_path, capsys, fake_methods):
    for folder in ("x", "y", "out"):
        (tmp_path / folder).mkdir()
    write_scene(tmp_path / "x" / "t.laz")
    write_scene(tmp_path / "y" / "t.laz")
    code, _, err = run_cli(capsys, "filter", tmp_path / "x", tmp_path / "y", "-o", tmp_path / "out",
                           "--method", "fake")
    assert code == 2 and "would both write it" in error_line(err)
    assert os.listdir(tmp_path / "out") == []


def test_instances_add_a_uint32_dimension(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake_inst",
                           "--instances")
    assert code == 0, err
    las = laspy.read(tmp_path / "out.laz")
    assert "instance_id" in las.point_format.extra_dimension_names
    assert las["instance_id"].dtype == np.uint32
    np.testing.assert_array_equal(las["instance_id"], np.arange(8) % 3)
    assert "instance_id" not in laspy.read(src).point_format.extra_dimension_names


def test_instances_from_a_method_without_them(tmp_path, capsys, fake_methods):
    src = write_scene(tmp_path / "in.laz")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake", "--instances")
    assert code == 2
    assert error_line(err) == "gfjax: error: --instances: method fake gives no instance ids"
    assert sorted(os.listdir(tmp_path)) == ["in.laz"]


def test_dtm_option_writes_a_geotiff_with_the_crs(tmp_path, capsys, fake_methods):
    pytest.importorskip("gfjax.dtm")
    rasterio = pytest.importorskip("rasterio")
    src = write_scene(tmp_path / "in.laz")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake",
                           "--dtm", tmp_path / "dtm.tif", "--cell", "2")
    assert code == 0, err
    with rasterio.open(tmp_path / "dtm.tif") as dtm:
        assert dtm.crs.to_epsg() == 32632
        assert dtm.res == (2.0, 2.0)


def test_hillshade_option_writes_each_dtms_shade_beside_it(tmp_path, capsys, fake_methods):
    pytest.importorskip("gfjax.dtm")
    import matplotlib.image
    import rasterio

    src = write_scene(tmp_path / "in.laz")
    args = ("filter", src, "-o", tmp_path / "out.laz", "--method", "fake", "--dtm", tmp_path / "dtm.tif", "--cell", "2")
    code, _, err = run_cli(capsys, *args, "--hillshade")
    assert code == 0, err
    shade = matplotlib.image.imread(tmp_path / "dtm.png")
    with rasterio.open(tmp_path / "dtm.tif") as dtm:
        assert shade.ndim == 3 and shade.shape[:2] == dtm.shape
    (tmp_path / "out.laz").unlink()
    (tmp_path / "dtm.tif").unlink()
    code, _, err = run_cli(capsys, *args, "--hillshade")          # the shade left there: refused, nothing written
    assert code == 2 and "--hillshade" in error_line(err) and "dtm.png" in error_line(err)
    assert sorted(os.listdir(tmp_path)) == ["dtm.png", "in.laz"]
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "fake", "--hillshade")
    assert code == 2 and error_line(err) == "gfjax: error: --hillshade: needs --dtm (the DTMs it shades)"


def test_unknown_method_and_missing_package(tmp_path, capsys, monkeypatch):
    src = write_scene(tmp_path / "in.laz")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "nosuch")
    assert code == 2 and "--method: unknown method 'nosuch'" in error_line(err)
    monkeypatch.setitem(methods.PACKAGES, "ghost", "gfjax._no_such_method_package")
    code, _, err = run_cli(capsys, "filter", src, "-o", tmp_path / "out.laz", "--method", "ghost")
    assert code == 2 and "method 'ghost' is not available" in error_line(err)
    assert sorted(os.listdir(tmp_path)) == ["in.laz"]


def test_input_spelled_differently_is_not_overwritten(tmp_path, capsys, fake_methods, monkeypatch):
    src = write_scene(tmp_path / "in.laz")
    before = src.read_bytes()
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli(capsys, "filter", "in.laz", "-o", tmp_path / "." / "in.laz", "--method", "fake")
    assert code == 2 and "is an input file; pass --force" in error_line(err)
    assert src.read_bytes() == before and fake_methods["fake"].calls == []
    code, _, err = run_cli(capsys, "filter", "in.laz", "-o", "in.laz", "--method", "fake", "--force")
    assert code == 0, err
    assert src.read_bytes() != before and sorted(os.listdir(tmp_path)) == ["in.laz"]


def _las_1_0(path):
    """A LAS 1.2 / format 1 file of 50 points with its version byte set to 1.0."""
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    rng = np.random.default_rng(0)
    las.x, las.y, las.z = rng.uniform(0, 20, 50), rng.uniform(0, 20, 50), rng.uniform(0, 1, 50)
    las.intensity = rng.integers(0, 60000, 50)
    las.gps_time = rng.uniform(0, 1e5, 50)
    las.classification = np.full(50, 1, np.uint8)
    las.write(path)
    data = bytearray(path.read_bytes())
    data[25] = 0                                     # version minor
    path.write_bytes(bytes(data))
    return path


def test_a_las_1_0_file_filters_and_is_written_as_las_1_2(tmp_path, capsys, fake_methods):
    source = _las_1_0(tmp_path / "old.las")
    code, out, _ = run_cli(capsys, "info", source)
    assert code == 0 and "LAS 1.0" in out
    target = tmp_path / "out.las"
    code, _, err = run_cli(capsys, "filter", source, "-o", target, "--method", "fake")
    assert code == 0, err
    notes = [line for line in err.splitlines() if "written as LAS 1.2" in line]
    assert len(notes) == 1 and str(source) in notes[0] and "LAS 1.0" in notes[0]
    before, after = laspy.read(source), laspy.read(target)
    assert (after.header.version.major, after.header.version.minor) == (1, 2)
    assert after.header.point_format.id == 1
    for name in before.point_format.dimension_names:
        if name != "classification":
            np.testing.assert_array_equal(np.asarray(after[name]), np.asarray(before[name]), err_msg=name)
