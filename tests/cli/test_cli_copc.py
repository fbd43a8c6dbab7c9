"""An output named `.copc.laz` is a COPC file (laspy's COPC reader reads every point) with the
classes a plain output gets; what COPC cannot hold, or out-of-core filtering cannot build, is
refused before any work."""
from __future__ import annotations

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, run_cli  # noqa: F401

import gfjax
from gfjax.io import copc

pytest.importorskip("copclib")


def scene(path, *, n=5000, seed=0, x0=0.0, point_format=1, version="1.2"):
    """Gently rolling ground with 5 m boxes on it, LAS 1.2 / format 1 (GPS time), unique points."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([x0, 0], [x0 + 60, 60], (n, 2))
    z = 20 + np.sin(xy[:, 0] / 9) + 5.0 * ((xy[:, 0] % 20 < 5) & (xy[:, 1] % 20 < 5))
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets = np.array([0.001] * 3), np.array([600_000.0, 4_000_000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xy[:, 0] + 600_000, xy[:, 1] + 4_000_000, z
    las.intensity = rng.integers(0, 60000, n)
    las.classification = np.ones(n, np.uint8)
    if "gps_time" in las.point_format.dimension_names:
        las.gps_time = rng.uniform(0, 1e5, n)
    las.write(path)
    return path


def by_place(las: laspy.LasData) -> np.ndarray:
    return np.lexsort((np.asarray(las.Z), np.asarray(las.Y), np.asarray(las.X)))


def assert_same_points(copc_out, plain_out):
    a, b = laspy.read(copc_out), laspy.read(plain_out)
    ia, ib = by_place(a), by_place(b)
    assert len(a.points) == len(b.points)
    for name in ("X", "Y", "Z", "intensity", "gps_time", "classification"):
        np.testing.assert_array_equal(np.asarray(a[name])[ia], np.asarray(b[name])[ib], err_msg=name)


def test_a_copc_output_is_a_copc_file_with_the_plain_outputs_points_and_classes(tmp_path, capsys, fake_methods):
    source = scene(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.copc.laz", "--method", "fake")
    assert code == 0, err
    notes = [line for line in err.splitlines() if "written as COPC in LAS 1.4 point format 6" in line]
    assert len(notes) == 1 and "LAS 1.2 point format 1" in notes[0]
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.laz", "--method", "fake")
    assert code == 0, err
    assert copc.is_copc(tmp_path / "out.copc.laz") and not copc.is_copc(tmp_path / "out.laz")
    with laspy.CopcReader.open(tmp_path / "out.copc.laz") as reader:
        assert len(reader.query()) == 5000
    assert_same_points(tmp_path / "out.copc.laz", tmp_path / "out.laz")
    assert set(np.unique(laspy.read(tmp_path / "out.copc.laz").classification)) == {1, 2}


def test_a_survey_of_copc_files_writes_copc_files(tmp_path, capsys, fake_methods):
    folder, out, plain = (tmp_path / name for name in ("in", "out", "plain"))
    for f in (folder, out, plain):
        f.mkdir()
    inputs = []
    for k in range(2):
        src = scene(tmp_path / f"part{k}.las", seed=k, x0=60.0 * k)
        written = tmp_path / f"part{k}.copc.laz"
        assert run_cli(capsys, "filter", src, "-o", written, "--method", "fake")[0] == 0
        inputs.append(written.rename(folder / written.name))
    code, _, err = run_cli(capsys, "filter", *inputs, "-o", out, "--method", "fake")
    assert code == 0, err
    code, _, err = run_cli(capsys, "filter", *inputs, "-o", plain, "--method", "fake", "--independent")
    assert code == 0, err
    for source in inputs:
        assert copc.is_copc(out / source.name)
        with laspy.CopcReader.open(out / source.name) as reader:
            assert len(reader.query()) == 5000
        np.testing.assert_array_equal(laspy.read(out / source.name).classification,
                                      laspy.read(plain / source.name).classification)


def test_out_of_core_filtering_refuses_a_copc_output_before_any_work(tmp_path, capsys, fake_methods):
    source = scene(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.copc.laz", "--method", "smrf",
                           "--out-of-core")
    assert code == 2
    assert "out.copc.laz (COPC, an octree over every point) needs the file in memory" in error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.las"]


def test_a_waveform_file_is_refused_a_copc_output_before_any_work(tmp_path, capsys, fake_methods):
    source = scene(tmp_path / "wave.las", point_format=4, version="1.3")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.copc.laz", "--method", "fake")
    assert code == 2
    assert f"{source}: point format 4 carries waveform packets" in error_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wave.las"]


def test_hag_writes_its_heights_into_a_copc_file(tmp_path, capsys):
    source = scene(tmp_path / "in.las")
    las = laspy.read(source)
    las.classification = np.where(np.asarray(las.z) < 22.5, 2, 1).astype(np.uint8)
    las.write(source)
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "hag.copc.laz")
    assert code == 0, err
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "hag.laz")
    assert code == 0, err
    with laspy.CopcReader.open(tmp_path / "hag.copc.laz") as reader:
        points = reader.query()
        assert "HeightAboveGround" in points.point_format.dimension_names and len(points) == 5000
    a, b = laspy.read(tmp_path / "hag.copc.laz"), laspy.read(tmp_path / "hag.laz")
    np.testing.assert_array_equal(np.asarray(a.HeightAboveGround)[by_place(a)],
                                  np.asarray(b.HeightAboveGround)[by_place(b)])


def test_the_api_writes_copc_by_the_name(tmp_path):
    cloud = gfjax.Cloud.from_xyz(np.random.default_rng(0).uniform(0, 30, (2000, 3)))
    out = gfjax.write(cloud, tmp_path / "api.copc.laz")
    assert copc.is_copc(out)
