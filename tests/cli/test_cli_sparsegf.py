"""`gfjax train` and `--model`: dry run, bad data, bad model files (exit 2, one line naming the file)."""
from __future__ import annotations

import laspy
import numpy as np
from cli_helpers import error_line, run_cli, write_scene


def test_train_dry_run_prints_the_parameter_count(tmp_path, capsys):
    scene = write_scene(tmp_path / "a.las")
    code, out, _ = run_cli(capsys, "train", scene, "-o", tmp_path / "m.eqx", "--dry-run")
    assert code == 0 and "tiny: 831,160 parameters" in out and "1 patches per epoch" in out
    code, out, _ = run_cli(capsys, "train", scene, "-o", tmp_path / "m.eqx", "--dry-run", "--preset", "paper")
    assert code == 0 and "paper: 37,917,608 parameters" in out
    assert not (tmp_path / "m.eqx").exists()


def test_train_refuses_a_file_without_ground(tmp_path, capsys):
    scene = write_scene(tmp_path / "a.las")
    las = laspy.read(scene)
    las.classification = np.where(las.classification == 2, 1, las.classification)
    las.write(tmp_path / "noground.las")
    code, _, err = run_cli(capsys, "train", scene, tmp_path / "noground.las", "-o", tmp_path / "m.eqx", "--dry-run")
    assert code == 2 and "noground.las: no point of class 2" in error_line(err)


def test_train_refuses_an_existing_model_and_a_missing_folder(tmp_path, capsys):
    scene = write_scene(tmp_path / "a.las")
    (tmp_path / "m.eqx").write_bytes(b"x")
    code, _, err = run_cli(capsys, "train", scene, "-o", tmp_path / "m.eqx")
    assert code == 2 and "exists" in error_line(err)
    code, _, err = run_cli(capsys, "train", scene, "-o", tmp_path / "no" / "m.eqx")
    assert code == 2 and "does not exist" in error_line(err)


def test_bad_model_files_exit_2_before_any_output(tmp_path, capsys):
    scene = write_scene(tmp_path / "a.las")
    (tmp_path / "junk.eqx").write_bytes(b"PK\x03\x04 junk")
    cases = {tmp_path / "missing.eqx": "model file not found", tmp_path / "junk.eqx": "not a gfjax SparseGF model"}
    for model, message in cases.items():
        code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.las", "--method", "sparsegf",
                               "--model", model)
        line = error_line(err)
        assert code == 2 and message in line and model.name in line
        assert not (tmp_path / "out.las").exists()
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.las", "--method", "smrf",
                           "--model", tmp_path / "junk.eqx")
    assert code == 2 and "only --method sparsegf takes a model" in error_line(err)


def test_train_never_replaces_its_data_or_a_point_cloud(tmp_path, capsys):
    scene = write_scene(tmp_path / "a.las")
    before = scene.read_bytes()
    code, _, err = run_cli(capsys, "train", scene, "-o", scene, "--force")
    assert code == 2 and "a model file, not a point cloud" in error_line(err)
    named = tmp_path / "data.eqx"                 # a training file under a model's name
    named.write_bytes(before)
    code, _, err = run_cli(capsys, "train", named, "-o", named, "--force", "--dry-run")
    assert code == 2 and "is a file it trains on" in error_line(err) and "data.eqx" in error_line(err)
    assert scene.read_bytes() == before and named.read_bytes() == before


def test_a_model_of_nan_weights_exits_2_naming_it(tmp_path, capsys):
    import jax

    from gfjax.sparsegf import checkpoint

    model, header = checkpoint.load()
    broken = jax.tree.map(lambda a: a * np.nan if hasattr(a, "dtype") and np.issubdtype(a.dtype, np.floating) else a,
                          tuple(model))
    path = tmp_path / "nan.eqx"
    checkpoint.save(path, type(model)(*broken), header["meta"])
    scene = write_scene(tmp_path / "a.las")
    code, _, err = run_cli(capsys, "filter", scene, "-o", tmp_path / "out.las", "--method", "sparsegf",
                           "--model", path)
    line = error_line(err)
    assert code == 2 and "nan.eqx" in line and "not finite" in line
    assert not (tmp_path / "out.las").exists()


def test_a_cloud_far_sparser_than_the_models_keeps_smrfs_labels_and_says_so(tmp_path, capsys):
    import gfjax

    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 400, (3000, 2))                      # 0.02 points/m²: the model saw 0.064-24.5
    z = 50 + 0.02 * xy[:, 0] + rng.normal(0, 0.05, len(xy))
    z[:300] += rng.uniform(3, 20, 300)
    source = tmp_path / "sparse.las"
    gfjax.write(gfjax.Cloud.from_xyz(np.column_stack([xy, z])), source)
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "sgf.las", "--method", "sparsegf")
    assert code == 0, err
    notes = [line for line in err.splitlines() if "SMRF's labels kept" in line]
    assert len(notes) == 1 and "sparse.las" in notes[0] and "beyond the 0.0639-24.5" in notes[0]
    code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "smrf.las", "--method", "smrf")
    assert code == 0, err
    np.testing.assert_array_equal(laspy.read(tmp_path / "sgf.las").classification,
                                  laspy.read(tmp_path / "smrf.las").classification)
