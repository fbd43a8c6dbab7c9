"""Synthetic MASF test scenes (shared by the tests and `make_golden.py`)."""
from __future__ import annotations

import numpy as np

BUILDINGS = [  # x0, x1, y0, y1 [m], roof height above ground [m]
    (12.0, 24.0, 30.0, 40.0, 8.0),
    (36.0, 44.0, 10.0, 25.0, 5.0),
]


def town(seed: int = 0, size_m: float = 56.0, density_per_m2: float = 1.2):
    """Gently sloped, slightly rough ground with two flat-roofed buildings (last pulse: roof
    points only inside a footprint), at UTM-like coordinates.

    Returns:
      `(xyz, ground, roof_id)`: float64 `(n, 3)` metres, bool truth `(n,)`, int `(n,)` the
      building index + 1 of a roof point, 0 on the ground.
    """
    rng = np.random.default_rng(seed)
    n = int(density_per_m2 * size_m * size_m)
    xy = rng.uniform(0.0, size_m, (n, 2))
    z = 200.0 + 0.04 * xy[:, 0] + 0.5 * np.sin(xy[:, 1] / 9.0) + rng.normal(0.0, 0.03, n)
    roof_id = np.zeros(n, dtype=np.int64)
    for i, (x0, x1, y0, y1, height) in enumerate(BUILDINGS):
        inside = (xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)
        z[inside] += height
        roof_id[inside] = i + 1
    xyz = np.column_stack([xy + np.array([512_000.0, 5_403_000.0]), z])
    return xyz, roof_id == 0, roof_id


def hilly_town(seed: int = 0, size_m: float = 48.0):
    """`town` on a 10 m hill and a 3 m terrace step, with 5 % of the points lifted 1-6 m (low
    vegetation): terrain where the TIN climbs within a layer, so extra test passes accept
    points (the densification's retests have work to do). Returns `(xyz, ground, roof_id)`."""
    xyz, ground, roof_id = town(seed=seed, size_m=size_m)
    rng = np.random.default_rng(seed)
    x, y = xyz[:, 0] - 512_000.0, xyz[:, 1] - 5_403_000.0
    xyz[:, 2] += 10.0 * np.exp(-((x - 30.0) / 6.0) ** 2 - ((y - 12.0) / 8.0) ** 2) + 3.0 * np.clip((y - 24.0) / 3.0, 0, 1)
    lifted = rng.random(len(xyz)) < 0.05
    xyz[lifted, 2] += rng.uniform(1.0, 6.0, lifted.sum())
    return xyz, ground & ~lifted, roof_id
