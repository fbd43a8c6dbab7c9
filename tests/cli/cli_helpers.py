"""Helpers of the CLI tests: small LAS files, a fake ground filter, running `gfjax` in-process."""
from __future__ import annotations

import dataclasses
import sys
import types
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from gfjax import cache
from gfjax.cli import main as cli_main
from gfjax.method import Method
from gfjax.result import Result

# Classes of the 8 points of `write_scene`: a mix of ground, vegetation, building, noise.
SCENE_CLASSES = np.array([2, 2, 1, 3, 6, 2, 7, 0], dtype=np.uint8)
SCENE_Z = np.array([0.0, 0.1, 0.2, 3.0, 8.0, 9.0, -5.0, 0.3])


UTM32N = pyproj.CRS.from_epsg(32632)


def write_scene(path: Path, *, crs: pyproj.CRS | None = UTM32N,
                returns: np.ndarray | None = None) -> Path:
    """An 8-point LAS 1.4 / format 6 file on a 2 m grid near UTM 32N coordinates."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 5_400_000.0, 0.0])
    if crs is not None:
        header.add_crs(crs)
    las = laspy.LasData(header)
    n = len(SCENE_Z)
    las.x = 500_000.0 + 2.0 * (np.arange(n) % 4)
    las.y = 5_400_000.0 + 2.0 * (np.arange(n) // 4)
    las.z = SCENE_Z
    las.classification = SCENE_CLASSES
    las.intensity = np.arange(n, dtype=np.uint16) * 100
    las.return_number = np.ones(n, np.uint8) if returns is None else returns
    las.number_of_returns = np.full(n, 1 if returns is None else 2, np.uint8)
    las.write(path)
    return path


@dataclasses.dataclass(frozen=True)
class FakeConfig:
    cell_m: float = 1.0

    def __post_init__(self):
        if not self.cell_m > 0:
            raise ValueError(f"cell_m must be > 0, got {self.cell_m!r}")


@dataclasses.dataclass(frozen=True)
class FakeParams:
    threshold_m: float = 0.5  # ground iff z below the lowest used point + threshold_m

    def check(self):
        if not self.threshold_m >= 0:
            raise ValueError(f"threshold_m must be >= 0, got {self.threshold_m}")


def _fake_module(name: str, *, instances: bool, crash: bool = False) -> types.ModuleType:
    module = types.ModuleType(name)
    module.Config, module.Params = FakeConfig, FakeParams
    module.calls = []

    def filter(cloud, *, config=None, params=None, returns="all", progress=False, tiling=None):  # noqa: A001
        module.calls.append({"cloud": cloud, "config": config, "params": params, "returns": returns, "tiling": tiling})
        if crash:
            raise RuntimeError("fake method crashed")
        use = cloud.filter_mask(returns)
        z = cloud.xyz_m[:, 2]
        ground = use & (z <= z[use].min() + params.threshold_m)
        ids = (np.arange(cloud.n_points) % 3).astype(np.uint32) if instances else None
        return Result(ground=ground, diagnostics=None, instance_id=ids)

    module.filter = filter
    # labels point by point: a survey may run it tile by tile
    module.METHOD = Method(name, filter, FakeConfig, FakeParams, {"generous": {"threshold_m": 100.0}}, {},
                           tiles=True, tile_labels=True)
    return module


@pytest.fixture
def fake_methods(monkeypatch):
    """Registers methods "fake", "fake_inst" (gives instance ids) and "fake_crash"."""
    from gfjax import methods

    modules = {"fake": _fake_module("fake", instances=False),
               "fake_inst": _fake_module("fake_inst", instances=True),
               "fake_crash": _fake_module("fake_crash", instances=False, crash=True)}
    for name, module in modules.items():
        monkeypatch.setitem(sys.modules, f"_gfjax_test_{name}", module)
        monkeypatch.setitem(methods.PACKAGES, name, f"_gfjax_test_{name}")
    return modules


@pytest.fixture(autouse=True)
def no_compilation_cache(monkeypatch):
    """Keep the in-process tests from pointing JAX at the user's cache folder."""
    monkeypatch.setattr(cache, "setup", lambda: None)


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """`gfjax *argv` in-process: (exit code, stdout, stderr)."""
    code = cli_main.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def error_line(err: str) -> str:
    """The one `gfjax: error:` line of stderr (asserting there is exactly one, no traceback)."""
    lines = [line for line in err.splitlines() if line.startswith("gfjax: error:")]
    assert len(lines) == 1, err
    assert "Traceback" not in err, err
    return lines[0]
