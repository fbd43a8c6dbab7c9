"""Helpers of the bench tests: a small labelled synthetic scene written as LAZ."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj

from gfjax.io import las as las_io
from gfjax.io.cloud import Cloud


def scene_xyz(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 48 m x 48 m gently sloping terrain (class 2) with a 12 m x 12 m x 6 m flat-roofed
    building (class 6), ~1.3 points/m2, near UTM 32N coordinates. Returns `(xyz (n, 3) m,
    classes uint8 (n,))`."""
    rng = np.random.default_rng(seed)
    n = 3000
    xy = rng.uniform(0.0, 48.0, size=(n, 2))
    z = 0.05 * xy[:, 0] + 0.02 * xy[:, 1] + rng.normal(0.0, 0.03, size=n)
    roof = (np.abs(xy[:, 0] - 24.0) < 6.0) & (np.abs(xy[:, 1] - 24.0) < 6.0)
    z = np.where(roof, 6.0 + 0.05 * 24.0 + 0.02 * 24.0, z)
    classes = np.where(roof, np.uint8(6), np.uint8(2)).astype(np.uint8)
    xyz = np.column_stack([xy + np.array([500_000.0, 5_400_000.0]), z + 250.0])
    return xyz, classes


def write_scene_laz(path: Path, *, labelled: bool = True) -> Path:
    """The scene as a LAZ with EPSG:32632; all points class 0 when not `labelled`."""
    xyz, classes = scene_xyz()
    if not labelled:
        classes = np.zeros_like(classes)
    cloud = Cloud.from_xyz(xyz, classification=classes, scale=0.01)
    cloud.las.header.add_crs(pyproj.CRS.from_epsg(32632))
    las_io.write(cloud, path)
    return path
