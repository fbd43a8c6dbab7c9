"""Small synthetic scenes whose right answer is known (shared by the DMF tests)."""
from __future__ import annotations

import numpy as np

from gfjax.io.cloud import Cloud

SIZE_M = 48.0            # scene side [m]; W = 1 m on these scenes, so rasters are 48 x 48
SPACING_M = 0.5          # grid spacing of the points [m]
BOX = (16.0, 32.0, 18.0, 34.0)   # building footprint x0, x1, y0, y1 [m]
BOX_HEIGHT_M = 8.0


def _grid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, SIZE_M, SPACING_M) + SPACING_M / 4
    x, y = np.meshgrid(g, g)
    xy = np.stack([x.ravel(), y.ravel()], axis=1)
    return xy + rng.uniform(-0.1, 0.1, xy.shape)


def box_scene(seed: int = 0) -> tuple[Cloud, np.ndarray, np.ndarray]:
    """Flat ground (z ~ 100 m, 2 cm noise) with one flat-roofed box building.

    Returns: `(cloud, ground, on_roof)`: the cloud (float64 metres), the true ground flag and
    the roof flag per point.
    """
    rng = np.random.default_rng(seed + 1)
    xy = _grid(seed)
    x0, x1, y0, y1 = BOX
    roof = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
    z = 100.0 + rng.normal(0, 0.02, len(xy)) + np.where(roof, BOX_HEIGHT_M, 0.0)
    xyz = np.column_stack([xy + 500_000.0, z])
    ground = ~roof
    return Cloud.from_xyz(xyz, classification=np.where(ground, 2, 1)), ground, roof


def ramp_scene(seed: int = 0, slope: float = 0.3) -> tuple[Cloud, np.ndarray]:
    """A plane rising `slope` (rise over run) to the east, no object. Returns `(cloud, ground)`."""
    rng = np.random.default_rng(seed + 2)
    xy = _grid(seed)
    z = 50.0 + slope * xy[:, 0] + rng.normal(0, 0.02, len(xy))
    xyz = np.column_stack([xy + 300_000.0, z])
    return Cloud.from_xyz(xyz, classification=np.full(len(xy), 2)), np.ones(len(xy), bool)


SHRUB_PATCH = (8.0, 40.0, 8.0, 40.0)   # understory footprint x0, x1, y0, y1 [m]
SHRUB_HEIGHT_M = 0.45


def shrub_scene(seed: int = 0) -> tuple[Cloud, np.ndarray]:
    """Flat ground (z ~ 100 m, 2 cm noise) under a patch of low understory: inside
    `SHRUB_PATCH` half of the 1 m cells (a checkerboard) hold one point `SHRUB_HEIGHT_M` above
    the ground among their four. Same x, y as `box_scene`.

    Returns: `(cloud, shrub)`: the cloud and the understory flag per point (all else ground).
    """
    rng = np.random.default_rng(seed + 3)
    xy = _grid(seed)
    x0, x1, y0, y1 = SHRUB_PATCH
    inside = (xy[:, 0] >= x0) & (xy[:, 0] < x1) & (xy[:, 1] >= y0) & (xy[:, 1] < y1)
    n_side = round(SIZE_M / SPACING_M)
    row, col = np.divmod(np.arange(len(xy)), n_side)               # grid indices (y, x)
    shrub = inside & (row % 2 == 0) & (col % 2 == 0) & ((row // 2 + col // 2) % 2 == 0)
    z = 100.0 + rng.normal(0, 0.02, len(xy)) + np.where(shrub, SHRUB_HEIGHT_M, 0.0)
    xyz = np.column_stack([xy + 700_000.0, z])
    return Cloud.from_xyz(xyz, classification=np.where(shrub, 1, 2)), shrub
