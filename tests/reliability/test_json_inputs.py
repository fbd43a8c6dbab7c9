"""Catalogue: JSON a user hands gfjax (params files, model and training-state headers) that is
huge, nested too deeply, or not a file -> exit 2 / `InputError`, never a RecursionError."""
from __future__ import annotations

import os

import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli  # noqa: F401
from reliability_files import run_gfjax, write_las

from gfjax.errors import InputError
from gfjax.io import params_file
from gfjax.sparsegf import checkpoint

DEEP = "[" * 200_000 + "]" * 200_000


def _filter_with_params(capsys, tmp_path, params, *fragments):
    source = write_las(tmp_path / "tile.las")
    before = sorted(os.listdir(tmp_path))
    code, out, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.laz", "--method", "fake",
                             "--params", params)
    assert code == 2, (out, err)
    line = error_line(err)
    assert f"--params {params}" in line, line
    for fragment in fragments:
        assert fragment in line, line
    assert sorted(os.listdir(tmp_path)) == before


def test_params_file_nested_too_deeply_exits_2(capsys, fake_methods, tmp_path):
    params = tmp_path / "deep.json"
    params.write_text('{"method": "fake", "values": ' + "[" * 100_000 + "]" * 100_000 + "}")
    _filter_with_params(capsys, tmp_path, params, "JSON nested too deeply")


def test_params_file_larger_than_a_mebibyte_exits_2(capsys, fake_methods, tmp_path):
    params = tmp_path / "huge.json"
    params.write_text('{"method": "fake", "values": {}, "pad": "' + "x" * (2 << 20) + '"}')
    _filter_with_params(capsys, tmp_path, params, "larger than 1048576 bytes")


def test_params_fifo_exits_2_without_blocking(tmp_path):
    source = write_las(tmp_path / "tile.las")
    fifo = tmp_path / "params.json"
    os.mkfifo(fifo)
    done = run_gfjax("filter", source, "-o", tmp_path / "out.laz", "--params", fifo, timeout=60)
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and f"--params {fifo}: not a regular file" in done.stderr
    assert not (tmp_path / "out.laz").exists()


def test_params_folder_exits_2(capsys, fake_methods, tmp_path):
    folder = tmp_path / "params.json"
    folder.mkdir()
    _filter_with_params(capsys, tmp_path, folder, "not a regular file")


def test_read_params_of_a_deep_array_raises_input_error(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text(DEEP)
    with pytest.raises(InputError, match="nested too deeply"):
        params_file.read_params(path)


def test_model_header_nested_too_deeply_raises_input_error(tmp_path):
    path = tmp_path / "model.eqx"
    path.write_bytes(b"[" * 60_000 + b"\n")
    with pytest.raises(InputError, match="not a gfjax SparseGF model"):
        checkpoint.read_header(path)


def test_model_name_too_long_raises_input_error(tmp_path):
    with pytest.raises(InputError, match="File name too long"):
        checkpoint.read_header(tmp_path / ("m" * (os.pathconf("/", "PC_NAME_MAX") + 1)))


def test_model_fifo_is_not_opened(tmp_path):
    fifo = tmp_path / "model.eqx"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="model file not found"):
        checkpoint.read_header(fifo)


def test_training_state_nested_too_deeply_counts_no_epochs(tmp_path):
    path = tmp_path / "state.eqx"
    path.write_bytes(b"[" * 60_000 + b"\n")
    assert checkpoint.state_epoch(path) == 0


def test_a_model_header_with_a_voxel_finer_than_its_keys_raises_input_error(tmp_path):
    """The shipped model's file with `voxel_m` 1e-6 in its header: refused when loaded (its
    settings pass the ranges of `--set`), not at the first patch."""
    import json

    from gfjax.sparsegf.filter import load_model

    shipped = checkpoint.shipped_path()
    with open(shipped, "rb") as f:
        header = json.loads(f.readline())
        body = f.read()
    header["meta"]["config"]["voxel_m"] = 1e-6
    path = tmp_path / "model.eqx"
    path.write_bytes(json.dumps(header).encode() + b"\n" + body)
    with pytest.raises(InputError, match="model settings are unusable .*voxel_m must be >= 0.05"):
        load_model(path)
