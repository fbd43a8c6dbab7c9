"""`--ignore-class` and `--keep-class`: which points a filter uses and which keep their class,
in memory, out of core and in a survey; the class rules themselves (`gfjax.io.asprs.ClassRules`)."""
from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest
from cli_helpers import error_line, fake_methods, run_cli  # noqa: F401

import gfjax
from gfjax.errors import SettingError
from gfjax.io import asprs

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data"
AHN3 = SHARED / "corpus" / "tudelft3d_3dfier" / "ahn3_cropped_1.laz"
# ground, unclassified, building, water, a user class, noise
CODES = np.array([2, 1, 6, 9, 64, 7])


def write_classes(path: Path, *, x0: float = 0.0, n: int = 600, seed: int = 0) -> Path:
    """A 30 x 20 m LAS 1.4 file of flat ground (z 0-0.3 m) whose points cycle through `CODES`."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    las = laspy.LasData(header)
    las.x, las.y = x0 + rng.uniform(0, 30, n), rng.uniform(0, 20, n)
    las.z = rng.uniform(0, 0.3, n)
    las.classification = CODES[np.arange(n) % len(CODES)].astype(np.uint8)
    las.write(path)
    return path


def classes_of(path: Path) -> np.ndarray:
    return np.asarray(laspy.read(path).classification)


def used_classes(fake) -> set[int]:
    """The classes of the points the fake method was last called to use."""
    cloud = fake["fake"].calls[-1]["cloud"]
    return set(np.unique(np.asarray(cloud.classification)[cloud.filter_mask("all")]).tolist())


def test_by_default_every_class_but_noise_is_used_and_relabelled(tmp_path, capsys, fake_methods):
    source = write_classes(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.las", "--method", "fake",
                           "--preset", "generous")
    assert code == 0, err
    before, after = classes_of(source), classes_of(tmp_path / "out.las")
    assert (after[before != 7] == 2).all()             # the generous fake calls every used point ground
    assert (after[before == 7] == 7).all()
    assert used_classes(fake_methods) == {1, 2, 6, 9, 64}


def test_keep_class_leaves_those_classes_as_they_were_and_uses_them(tmp_path, capsys, fake_methods):
    source = write_classes(tmp_path / "in.las")
    code, out, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.las", "--method", "fake",
                             "--preset", "generous", "--keep-class", "6,9,64")
    assert code == 0, err
    before, after = classes_of(source), classes_of(tmp_path / "out.las")
    kept = np.isin(before, [6, 9, 64, 7])
    np.testing.assert_array_equal(after[kept], before[kept])
    assert (after[~kept] == 2).all()
    assert used_classes(fake_methods) == {1, 2, 6, 9, 64}
    assert f"{int((~kept).sum()):,} ground of" in out          # the count is what the file says


def test_ignore_class_keeps_water_out_of_the_filter_and_its_class(tmp_path, capsys, fake_methods):
    source = write_classes(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.las", "--method", "fake",
                           "--preset", "generous", "--ignore-class", "9", "--keep-class", "6")
    assert code == 0, err
    before, after = classes_of(source), classes_of(tmp_path / "out.las")
    assert used_classes(fake_methods) == {1, 2, 6, 64}
    same = np.isin(before, [6, 7, 9])
    np.testing.assert_array_equal(after[same], before[same])
    assert (after[~same] == 2).all()


def test_an_ignored_class_is_as_if_its_points_were_not_there(tmp_path, capsys):
    """SMRF on a file with water ignored labels every other point as on the file without water."""
    rng = np.random.default_rng(1)
    n = 3000
    xy = rng.uniform(0, 60, (n, 2))
    z = 0.05 * xy[:, 0] + rng.normal(0, 0.05, n)
    water = (xy[:, 0] > 40) & (rng.random(n) < 0.5)
    z[water] -= 1.5                                      # a pond a filter would take as ground
    codes = np.where(water, 9, 1).astype(np.uint8)
    full = gfjax.Cloud.from_xyz(np.column_stack([xy, z]), classification=codes)
    dry = gfjax.Cloud.from_xyz(np.column_stack([xy, z])[~water], classification=codes[~water])
    gfjax.write(full, tmp_path / "full.las")
    gfjax.write(dry, tmp_path / "dry.las")
    for name in ("full", "dry"):
        code, _, err = run_cli(capsys, "filter", tmp_path / f"{name}.las", "-o", tmp_path / f"{name}_out.las",
                               "--ignore-class", "9", "--method", "smrf", "--preset", "fixed")
        assert code == 0, err
    full_out, dry_out = classes_of(tmp_path / "full_out.las"), classes_of(tmp_path / "dry_out.las")
    np.testing.assert_array_equal(full_out[~water], dry_out)
    assert (full_out[water] == 9).all()


@pytest.mark.parametrize("mode", ["--out-of-core", "survey"])
def test_keep_and_ignore_hold_out_of_core_and_in_a_survey(tmp_path, capsys, mode):
    sources = [write_classes(tmp_path / "a.las", seed=2), write_classes(tmp_path / "b.las", x0=30.0, seed=3)]
    out = tmp_path / "out"
    out.mkdir()
    extra = ["--out-of-core", "--independent"] if mode == "--out-of-core" else []
    code, _, err = run_cli(capsys, "filter", *sources, "-o", out, "--method", "smrf", "--keep-class", "6,64",
                           "--ignore-class", "9", *extra)
    assert code == 0, err
    for source in sources:
        before, after = classes_of(source), classes_of(out / source.name)
        same = np.isin(before, [6, 64, 7, 9])
        np.testing.assert_array_equal(after[same], before[same])
        assert set(np.unique(after[~same]).tolist()) <= {1, 2}
        assert (after[~same] == 2).mean() > 0.9            # flat ground within 0.3 m: mostly ground


@pytest.mark.parametrize("value, fragment", [("6,x", "'x' is not a class code"), ("300", "class 300 is not"),
                                             ("", "'' is not a class code")])
@pytest.mark.parametrize("option", ["--keep-class", "--ignore-class"])
def test_a_bad_class_list_exits_2_naming_the_option(tmp_path, capsys, fake_methods, option, value, fragment):
    source = write_classes(tmp_path / "in.las")
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.las", "--method", "fake", option, value)
    assert code == 2
    assert option in err and fragment in err, err
    assert not (tmp_path / "out.las").exists()


def test_class_rules_always_ignore_noise_and_refuse_codes_outside_0_255():
    rules = asprs.ClassRules(ignore={9}, keep={6})
    assert rules.ignore == {7, 9, 18} and rules.keep == {6}
    assert asprs.ClassRules().ignore == {7, 18}
    with pytest.raises(SettingError, match="keep classes must be ASPRS codes 0-255, got 256"):
        asprs.ClassRules(keep={256})
    with pytest.raises(SettingError, match="got -1"):
        asprs.ClassRules(ignore={-1})


def test_relabel_never_changes_a_kept_or_unused_class():
    rng = np.random.default_rng(0)
    cls = rng.choice(CODES, 500).astype(np.uint8)
    ground, used = rng.random(500) < 0.5, rng.random(500) < 0.8
    rules = asprs.ClassRules(keep={6, 64})
    for reset in (False, True):
        new = asprs.relabel(cls, ground, used, reset_nonground=reset, rules=rules)
        for i in range(500):                                     # one point at a time
            if not used[i] or cls[i] in (6, 64):
                expected = cls[i]
            elif ground[i]:
                expected = 2
            else:
                expected = 1 if reset or cls[i] == 2 else cls[i]
            assert new[i] == expected


def test_a_cloud_with_classes_ignores_and_keeps_them(tmp_path):
    cloud = gfjax.read(write_classes(tmp_path / "in.las")).with_classes(ignore={9}, keep={6})
    cls = cloud.classification
    np.testing.assert_array_equal(cloud.ignored, np.isin(cls, [7, 9]))
    out = cloud.with_ground(np.ones(cloud.n_points, bool))
    assert (out.classification[np.isin(cls, [6, 7, 9])] == cls[np.isin(cls, [6, 7, 9])]).all()


@pytest.mark.skipif(not AHN3.exists(), reason="needs ../shared/data/corpus")
def test_ahn3_buildings_water_and_its_user_class_survive_keep_class(tmp_path, capsys):
    before = classes_of(AHN3)
    code, _, err = run_cli(capsys, "filter", AHN3, "-o", tmp_path / "keep.laz", "--keep-class", "6,9,26")
    assert code == 0, err
    after = classes_of(tmp_path / "keep.laz")
    kept = np.isin(before, [6, 9, 26])
    np.testing.assert_array_equal(after[kept], before[kept])
    code, _, err = run_cli(capsys, "filter", AHN3, "-o", tmp_path / "plain.laz")
    assert code == 0, err
    plain = classes_of(tmp_path / "plain.laz")
    assert (plain[before == 9] == 2).sum() > 200          # without it, the water becomes ground
