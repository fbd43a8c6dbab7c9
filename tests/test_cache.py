"""The Python API keeps compiled programs across processes by default, as the CLI does;
`GFJAX_CACHE=0` turns that off."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

REPO = Path(__file__).resolve().parents[1]

_FILTER = r"""
import numpy as np
import gfjax
from gfjax import aot, smrf
compiled = []
aot.on_compile(compiled.append)
rng = np.random.default_rng(0)
xy = rng.uniform(0, 60, (3000, 2))
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + 5e5, 100 + 0.1 * xy[:, 0]]))
ground = smrf.filter(cloud).ground
import jax
print(aot.enabled_folder(), jax.config.jax_compilation_cache_dir or None, len(compiled), int(ground.sum()))
"""


def _run(tmp_path, **env) -> list[str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("GFJAX_CACHE", "GFJAX_EXPORT_CACHE", "JAX_COMPILATION_CACHE_DIR")} | env
    done = subprocess.run([sys.executable, "-c", _FILTER], capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={**env, "XDG_CACHE_HOME": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def test_a_new_python_process_loads_what_the_last_one_compiled(tmp_path):
    folder, jax_folder, compiled, ground = _run(tmp_path)
    assert folder == str(tmp_path / "gfjax" / "export") and jax_folder == str(tmp_path / "gfjax" / "jax")
    assert int(compiled) > 0
    assert _run(tmp_path) == [folder, jax_folder, "0", ground]      # nothing compiled the second time


@pytest.mark.parametrize("off", ["0", ""])
def test_gfjax_cache_0_turns_both_caches_off(tmp_path, off):
    folder, jax_folder, _, _ = _run(tmp_path, GFJAX_CACHE=off)
    assert folder == jax_folder == "None"
    assert not (tmp_path / "gfjax").exists()


def test_import_gfjax_changes_no_jax_setting_and_writes_nothing(tmp_path):
    script = ("import gfjax, gfjax.smrf, jax; from gfjax import aot; "
              "print(jax.config.jax_compilation_cache_dir or None, aot.enabled_folder())")
    env = {k: v for k, v in os.environ.items() if k not in ("GFJAX_CACHE", "GFJAX_EXPORT_CACHE")}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=120,
                          env={**env, "XDG_CACHE_HOME": str(tmp_path)})
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["None", "None"]
    assert not any(tmp_path.iterdir())
