"""JAX's persistent compilation cache holds executables: its folder obeys the same rule as
`gfjax.aot`'s (private to the user, 0700). A folder others can write, or a folder above it
that others can write, means no persistent cache for the process, with one warning line."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
_SCRIPT = ("from gfjax.cache import enable as e; folder = e(); "
           "import jax; print(folder, jax.config.jax_compilation_cache_dir or None)")  # "" is off too


def _enable(env: dict) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "GFJAX_EXPORT_CACHE")} | env
    return subprocess.run([sys.executable, "-c", _SCRIPT], capture_output=True, text=True, cwd=REPO, timeout=120,
                          env=env)


def _one_warning(err: str) -> None:
    lines = [line for line in err.splitlines() if line]
    assert len(lines) == 1 and lines[0].startswith("gfjax: warning: "), err


def test_private_folders_are_created_0700(tmp_path):
    done = _enable({"XDG_CACHE_HOME": str(tmp_path)})
    folder = tmp_path / "gfjax" / "jax"
    assert done.returncode == 0 and done.stderr == "", done.stderr
    assert done.stdout.split() == [str(folder), str(folder)]
    assert folder.stat().st_mode & 0o777 == 0o700
    assert (tmp_path / "gfjax" / "export").stat().st_mode & 0o777 == 0o700


def test_group_writable_jax_folder_is_refused(tmp_path):
    folder = tmp_path / "gfjax" / "jax"
    folder.mkdir(parents=True)
    folder.chmod(0o775)
    done = _enable({"XDG_CACHE_HOME": str(tmp_path), "GFJAX_EXPORT_CACHE": "0"})
    assert done.returncode == 0 and done.stdout.split() == ["None", "None"]
    _one_warning(done.stderr)
    assert f"{folder} can be written by other users" in done.stderr


def test_writable_folder_above_both_caches_gives_one_line(tmp_path):
    (tmp_path / "gfjax").mkdir()
    (tmp_path / "gfjax").chmod(0o777)
    done = _enable({"XDG_CACHE_HOME": str(tmp_path)})
    assert done.returncode == 0 and done.stdout.split() == ["None", "None"]
    _one_warning(done.stderr)                               # one line for both caches


def test_jax_cache_folder_named_by_the_user_is_checked(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    done = _enable({"XDG_CACHE_HOME": str(tmp_path / "home"), "JAX_COMPILATION_CACHE_DIR": str(shared)})
    assert done.returncode == 0 and done.stdout.split() == ["None", "None"]
    _one_warning(done.stderr)
    private = tmp_path / "private"
    done = _enable({"XDG_CACHE_HOME": str(tmp_path / "home"), "JAX_COMPILATION_CACHE_DIR": str(private)})
    assert done.returncode == 0 and done.stdout.split() == [str(private), str(private)], done.stderr


def test_jax_folder_behind_a_link_is_checked_where_it_points(tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "gfjax").symlink_to(shared, target_is_directory=True)
    done = _enable({"XDG_CACHE_HOME": str(tmp_path / "home")})
    assert done.returncode == 0 and done.stdout.split() == ["None", "None"]
    _one_warning(done.stderr)


@pytest.mark.parametrize("mode, shared", [(0o777, False), (0o700, True)])
def test_bench_compile_cache_must_be_private(tmp_path, monkeypatch, capsys, mode, shared):
    """`gfjax bench --compile-cache DIR` hands DIR to JAX in every child: a folder others can
    write is not shared (one warning line), a private one is."""
    from bench_helpers import write_scene_laz

    from gfjax.aot import folder as aot_folder
    from gfjax.bench import run as bench
    from gfjax.cli.main import main

    monkeypatch.setitem(aot_folder._state, "warned", False)
    scene = write_scene_laz(tmp_path / "scene.laz")
    cache = tmp_path / "cache"
    cache.mkdir()
    cache.chmod(mode)
    seen = {}

    def fake_iter_runs(files, runners, **kwargs):
        seen.update(kwargs)
        return iter(())

    monkeypatch.setattr(bench, "iter_runs", fake_iter_runs)
    assert main(["bench", str(scene), "--methods", "smrf", "--compile-cache", str(cache)]) == 0
    err = capsys.readouterr().err
    assert seen["compile_cache"] == (str(cache) if shared else None)
    assert ("gfjax: warning: " in err) is not shared


def test_a_link_planted_among_the_jax_cache_entries_turns_the_cache_off(tmp_path):
    folder = tmp_path / "gfjax" / "jax"
    folder.mkdir(parents=True, mode=0o700)
    (folder / "jit_f-0123-cache").write_bytes(b"ours")
    (folder / "jit_g-4567-cache").symlink_to(tmp_path / "elsewhere")
    done = _enable({"XDG_CACHE_HOME": str(tmp_path), "GFJAX_EXPORT_CACHE": "0"})
    assert done.returncode == 0 and done.stdout.split() == ["None", "None"]
    _one_warning(done.stderr)
    assert f"{folder / 'jit_g-4567-cache'}: a symbolic link" in done.stderr


def test_a_jax_cache_entry_of_another_user_is_found(tmp_path, monkeypatch):
    """Tests cannot chown: `os.lstat` reports another owner for one entry."""
    from gfjax import aot
    from gfjax.aot import folder as aot_folder

    (tmp_path / "a-cache").write_bytes(b"ours")
    (tmp_path / "b-cache").write_bytes(b"theirs")
    assert aot.planted_entry(tmp_path) is None
    real = os.lstat

    def lstat(path, *args, **kwargs):
        info = real(path, *args, **kwargs)
        if str(path).endswith("b-cache"):
            fields = list(tuple(info)[:10])
            fields[4] = 12345
            return os.stat_result(fields)
        return info

    monkeypatch.setattr(aot_folder.os, "lstat", lstat)
    assert aot.planted_entry(tmp_path) == f"{tmp_path / 'b-cache'} is owned by user 12345"
