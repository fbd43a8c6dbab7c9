"""The methods' `warm` (`gfjax warmup`): after it, a file of a size never seen before runs
without compiling anything, in a new process."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)


REPO = Path(__file__).resolve().parents[1]

# 100 m tiles with 10 m buffers: one canonical side (128 cells), so warming is one raster program
_SMALL = "gfjax.Tiling(tile_size_m=100.0, buffer_m=10.0)"
_WARM = f"import gfjax; from gfjax import smrf; print(smrf.warm(tiling={_SMALL}))"
_FILTER = f"""
import numpy as np, jax, gfjax
from gfjax import aot, smrf
compiled = []
aot.on_compile(compiled.append)
jax.monitoring.register_event_listener(
    lambda event, **_: compiled.append(event) if event == "/jax/compilation_cache/cache_misses" else None)
rng = np.random.default_rng(1)
xy = rng.uniform(0, [77, 53], (5000, 2))               # a window of 98 x 74 cells: never warmed as such
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + 5e5, 100 + 0.1 * xy[:, 0]]))
ground = smrf.filter(cloud, tiling={_SMALL}).ground
print(len(compiled), int(ground.sum()))
"""


def _python(script: str, cache: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("GFJAX_CACHE", "GFJAX_EXPORT_CACHE",
                                                           "JAX_COMPILATION_CACHE_DIR")}
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=REPO, timeout=600,
                          env={**env, "XDG_CACHE_HOME": str(cache)})
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_after_warm_a_new_size_compiles_nothing(tmp_path):
    # 1 side x 4 capacities: 16 k to 1 M points; a larger window runs 1 M points at a time
    assert _python(_WARM, tmp_path) == "4"
    compiled, ground = _python(_FILTER, tmp_path).split()
    assert compiled == "0" and int(ground) > 0


_SPARSEGF_FILTER = """
import logging
import numpy as np, jax, gfjax
from gfjax import aot, sparsegf
compiled, features = [], []
aot.on_compile(lambda module: compiled.append(module)
               if not module.startswith(("gfjax.smrf", "gfjax.sparsegf.vote")) else None)


class Features(logging.Handler):
    def emit(self, record):
        if "PERSISTENT COMPILATION CACHE MISS" in record.getMessage() and "_point_inputs" in record.getMessage():
            features.append(record.getMessage())


jax.config.update("jax_explain_cache_misses", True)
logging.getLogger("jax").addHandler(Features())
rng = np.random.default_rng(2)
xy = rng.uniform(0, [110, 70], (9000, 2))                # another size than the scene warm filters (SMRF: its side)
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + 6e5, 50 + 0.05 * xy[:, 1]]))
ground = sparsegf.filter(cloud).ground
small = rng.uniform(0, 15, (1500, 2))                    # a small pack's network
ground_small = sparsegf.filter(gfjax.Cloud.from_xyz(np.column_stack([small + 6e5, 50 + 0.01 * small[:, 0]]))).ground
tiny = rng.uniform(0, 15, (300, 2))                      # a tiny pack's network
ground_tiny = sparsegf.filter(gfjax.Cloud.from_xyz(np.column_stack([tiny + 6e5, 50 + 0.01 * tiny[:, 0]]))).ground
print(len(compiled), len(features), int(ground.sum()) * int(ground_small.sum()) * int(ground_tiny.sum()))
"""


def test_after_sparsegf_warm_its_network_and_feature_programs_are_loaded_not_compiled(tmp_path):
    """The network programs (a full pack, a small one, a tiny one) and the per-patch feature
    program of another patch size are loaded, not compiled (the vote program of a new cloud
    size still compiles, and is kept);
    SMRF's compiles are not counted: its surface is an input of the shipped model, and
    `smrf.warm` prepares those."""
    from gfjax.sparsegf.pipeline import WARM_KEPT, WARM_MEMBERS

    sizes = sum(k <= m for m in WARM_MEMBERS for k in WARM_KEPT)
    assert _python("from gfjax import sparsegf; print(sparsegf.warm())", tmp_path) == str(3 + sizes)
    compiled, features, ground = _python(_SPARSEGF_FILTER, tmp_path).split()
    assert compiled == "0" and features == "0" and int(ground) > 0


_CSF_FILTER = """
import numpy as np, gfjax
from gfjax import aot, csf
compiled = []
aot.on_compile(compiled.append)
rng = np.random.default_rng(3)
xy = rng.uniform(0, [163, 141], (4000, 2))               # a cloth of 145 x 167 particles: grid (192, 192)
cloud = gfjax.Cloud.from_xyz(np.column_stack([xy + 7e5, 20 + 0.2 * xy[:, 0]]))
ground = csf.filter(cloud).ground
print(len(compiled), int(ground.sum()))
"""


def test_after_csf_warm_its_cloth_program_is_loaded_not_compiled(tmp_path):
    """CSF's cloth programs (`start_cloth`, `advance_cloth`, `finish_cloth`) are warmed per
    grid; its two point programs compile on first use. A run with a progress bar (the command
    line's) runs the very programs a run without one does."""
    cold, warmed = tmp_path / "cold", tmp_path / "warm"
    compiled_cold, ground_cold = _python(_CSF_FILTER, cold).split()
    assert _python("from gfjax import csf; print(csf.warm(sides=(128, 192)))", warmed) == "4"
    compiled, ground = _python(_CSF_FILTER, warmed).split()
    assert (compiled_cold, compiled) == ("5", "2") and ground == ground_cold and int(ground) > 0
    shown = _python(_CSF_FILTER.replace("csf.filter(cloud)", "csf.filter(cloud, progress=True)"), warmed)
    assert shown.split() == ["0", ground]                 # the point programs: stored by the run above
