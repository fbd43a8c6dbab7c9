"""`gfjax cache`: the caches' folders and sizes, and emptying them without leaving their folders."""
from __future__ import annotations

import os

import cli_helpers
from cli_helpers import no_compilation_cache  # noqa: F401 (autouse fixture)


def _caches(tmp_path, monkeypatch):
    monkeypatch.setenv("GFJAX_CACHE", "1")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    for name in ("GFJAX_EXPORT_CACHE", "JAX_COMPILATION_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    jax_folder, store = tmp_path / "gfjax" / "jax", tmp_path / "gfjax" / "export"
    for folder, n in ((jax_folder, 3), (store, 2)):
        folder.mkdir(parents=True)
        for i in range(n):
            (folder / f"entry{i}").write_bytes(b"x" * 1024 * 1024)
    return jax_folder, store


def test_info_gives_each_cache_its_files_and_size(capsys, tmp_path, monkeypatch):
    jax_folder, store = _caches(tmp_path, monkeypatch)
    code, out, _ = cli_helpers.run_cli(capsys, "cache")
    assert code == 0
    assert f"JAX compilation cache: {jax_folder}: 3 files, 3.0 MiB (bound: 1 GiB)" in out
    assert f"gfjax program store: {store}: 2 files, 2.0 MiB (bound: 512 programs or 256 MiB)" in out


def test_clear_removes_the_entries_and_nothing_beyond_them(capsys, tmp_path, monkeypatch):
    jax_folder, store = _caches(tmp_path, monkeypatch)
    outside = tmp_path / "precious.txt"
    outside.write_text("keep")
    os.symlink(outside, store / "link")
    (store / "sub").mkdir()
    (store / "sub" / "inner").write_text("keep")
    code, out, _ = cli_helpers.run_cli(capsys, "cache", "clear")
    assert code == 0 and "removed 3 files, 3.0 MiB" in out and "removed 2 files, 2.0 MiB" in out
    assert sorted(p.name for p in jax_folder.iterdir()) == []
    assert sorted(p.name for p in store.iterdir()) == ["link", "sub"]
    assert outside.read_text() == "keep" and (store / "sub" / "inner").exists()
    code, out, _ = cli_helpers.run_cli(capsys, "cache")
    assert "0 files, 0.0 MiB" in out


def test_caches_turned_off_say_so(capsys, monkeypatch):
    monkeypatch.setenv("GFJAX_CACHE", "0")
    code, out, _ = cli_helpers.run_cli(capsys, "cache", "clear")
    assert code == 0 and out.splitlines() == ["JAX compilation cache: off", "gfjax program store: off"]


def test_a_bad_action_exits_2(capsys):
    code, _, err = cli_helpers.run_cli(capsys, "cache", "empty")
    assert code == 2 and err.startswith("gfjax: error:")
