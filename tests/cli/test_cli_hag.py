"""`gfjax hag`: heights above a TIN of the ground, as a HeightAboveGround dimension or as z; across
file borders; from a method's ground; bad inputs."""
from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, run_cli

import gfjax
from gfjax.dtm.hag import height_above_ground

BCTS_2 = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "lasR_bcts" / "bcts_2.laz"


def terrain(x0: float = 0.0, n: int = 4000, seed: int = 0):
    """A tilted plane z = 100 + 0.1 x + 0.05 y (class 2) and points at known heights over it (class 5)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform([x0, 0], [x0 + 50, 50], (n, 2))
    height = np.where(rng.random(n) < 0.4, rng.uniform(0.5, 20, n), 0.0)
    z = 100 + 0.1 * xy[:, 0] + 0.05 * xy[:, 1] + height
    cls = np.where(height > 0, 5, 2).astype(np.uint8)
    return np.column_stack([xy, z]), cls, height


def write(path, xyz, cls):
    cloud = gfjax.Cloud.from_xyz(xyz, classification=cls, scale=0.001)
    las = cloud.las
    las.intensity = np.arange(len(xyz)) % 60000
    gfjax.write(cloud, path)
    return path


def inside(xyz, cls, margin=2.0):
    """Points inside the ground's hull by `margin` (no extrapolation there)."""
    g = xyz[cls == 2]
    lo, hi = g[:, :2].min(axis=0) + margin, g[:, :2].max(axis=0) - margin
    return np.all((xyz[:, :2] > lo) & (xyz[:, :2] < hi), axis=1)


def test_heights_over_a_tilted_plane_are_the_heights_put_there(tmp_path, capsys):
    xyz, cls, height = terrain()
    source = write(tmp_path / "in.laz", xyz, cls)
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "hag.laz")
    assert code == 0, err
    before, after = laspy.read(source), laspy.read(tmp_path / "hag.laz")
    hag = np.asarray(after["HeightAboveGround"])
    assert hag.dtype == np.float64
    near = inside(xyz, cls)
    np.testing.assert_allclose(hag[near], height[near], atol=2e-3)      # the file's 1 mm z steps
    assert np.abs(hag[cls == 2]).max() < 1e-9
    for name in before.point_format.dimension_names:
        np.testing.assert_array_equal(np.asarray(after[name]), np.asarray(before[name]), err_msg=name)
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "norm.laz", "--normalize")
    assert code == 0, err
    normalized = laspy.read(tmp_path / "norm.laz")
    np.testing.assert_allclose(np.asarray(normalized.z), hag, atol=0.5e-3 + 1e-9)
    assert "HeightAboveGround" not in set(normalized.point_format.dimension_names)
    np.testing.assert_array_equal(normalized.X, before.X)
    np.testing.assert_array_equal(normalized.intensity, before.intensity)


def test_heights_agree_across_file_borders(tmp_path, capsys):
    a, a_cls, _ = terrain(0.0, seed=1)
    b, b_cls, _ = terrain(50.0, seed=2)
    a_cls = np.where(a[:, 0] > 40, 5, a_cls).astype(np.uint8)          # A's east strip: no ground
    sources = [write(tmp_path / "a.laz", a, a_cls), write(tmp_path / "b.laz", b, b_cls)]
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = run_cli(capsys, "hag", *sources, "-o", out)
    assert code == 0, err
    a, b = (gfjax.read(s).xyz_m for s in sources)                    # as stored: 1 mm steps
    both = np.concatenate([a, b])
    whole = height_above_ground(both, np.concatenate([a_cls, b_cls]) == 2)
    got = np.asarray(laspy.read(out / "a.laz")["HeightAboveGround"])
    np.testing.assert_allclose(got, whole[:len(a)], atol=1e-6)
    alone = height_above_ground(a, a_cls == 2)                          # what A alone would say
    assert np.abs(alone - whole[:len(a)])[a[:, 0] > 45].max() > 0.3


def test_a_method_classifies_first_and_its_ground_is_at_zero(tmp_path, capsys):
    xyz, cls, _ = terrain()
    source = write(tmp_path / "in.laz", xyz, np.ones(len(xyz), np.uint8))   # unclassified
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "hag.laz", "--method", "smrf")
    assert code == 0, err
    after = laspy.read(tmp_path / "hag.laz")
    ground = np.asarray(after.classification) == 2
    assert ground.sum() > 0.5 * (cls == 2).sum()
    assert np.abs(np.asarray(after["HeightAboveGround"])[ground]).max() < 1e-9


def test_no_ground_exits_2_naming_the_file(tmp_path, capsys):
    xyz, _, _ = terrain()
    source = write(tmp_path / "in.laz", xyz, np.ones(len(xyz), np.uint8))
    code, _, err = run_cli(capsys, "hag", source, "-o", tmp_path / "hag.laz")
    assert code == 2 and "in.laz: no ground point (class 2)" in error_line(err)
    assert not (tmp_path / "hag.laz").exists()


@pytest.mark.skipif(not BCTS_2.exists(), reason="needs ../shared/data")
def test_bcts_2_ground_is_at_zero(tmp_path, capsys):
    code, _, err = run_cli(capsys, "hag", BCTS_2, "-o", tmp_path / "hag.laz")
    assert code == 0, err
    after = laspy.read(tmp_path / "hag.laz")
    ground = np.asarray(after.classification) == 2
    assert np.abs(np.asarray(after["HeightAboveGround"])[ground]).max() < 0.01
