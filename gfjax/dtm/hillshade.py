"""Shaded relief of a DTM (host numpy), and its PNG.

Slopes use Horn's (1981) 3 x 3 finite differences, as GDAL's `gdaldem hillshade` does; the
shade is the cosine of the angle between the surface normal and the direction to the sun,
clipped to [0, 1] (self-shadowed slopes are 0; cast shadows are not traced).
"""
from __future__ import annotations

import math

import matplotlib.image
import numpy as np

from gfjax.io.atomic import atomic_output


def _neighbours(z: np.ndarray, valid: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """The 3 x 3 neighbourhood of every cell, offset (dr, dc) -> `(h, w)`.

    A neighbour outside the raster or without a value takes the centre cell's value, so the
    slope at a border or beside nodata is computed from the cells that exist (a one-sided
    difference along that direction).
    """
    h, w = z.shape
    padded = np.pad(np.where(valid, z, np.nan), 1, constant_values=np.nan)
    out = {}
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            shifted = padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w]
            out[(dr, dc)] = np.where(np.isnan(shifted), z, shifted)
    return out


def hillshade(z: np.ndarray, valid: np.ndarray, *, cell: float, z_factor: float = 1.0,
              azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """Illumination of a terrain lit by a distant sun.

    Args:
      z: elevations `(h, w)`, row 0 north; values where `~valid` are ignored.
      valid: cells with an elevation, bool `(h, w)`.
      cell: cell size, horizontal units.
      z_factor: converts z to the horizontal unit, `vertical_unit_m / horizontal_unit_m`
        (1 when both are metres or both feet; 3.2808 for z in m over x, y in ft).
      azimuth_deg: direction the light comes from, degrees clockwise from north (315 = NW).
      altitude_deg: sun elevation above the horizon, degrees.

    Returns:
      float64 `(h, w)` in [0, 1]: `n . s` for the unit surface normal `n` and the unit vector
      `s` to the sun, clipped at 0; NaN where `~valid`. A flat cell gives `sin(altitude)`.
    """
    z = np.asarray(z, dtype=np.float64)
    valid = np.asarray(valid, dtype=bool)
    if z.ndim != 2 or valid.shape != z.shape:
        raise ValueError(f"z and valid must be (h, w) rasters of one shape, got {z.shape}, {valid.shape}")
    nb = _neighbours(z, valid)
    # Horn (1981): weighted differences over the 3 x 3 window; y grows northwards (row - 1).
    east = nb[(-1, 1)] + 2 * nb[(0, 1)] + nb[(1, 1)]
    west = nb[(-1, -1)] + 2 * nb[(0, -1)] + nb[(1, -1)]
    north = nb[(-1, -1)] + 2 * nb[(-1, 0)] + nb[(-1, 1)]
    south = nb[(1, -1)] + 2 * nb[(1, 0)] + nb[(1, 1)]
    dz_dx = (east - west) * (z_factor / (8.0 * cell))
    dz_dy = (north - south) * (z_factor / (8.0 * cell))
    azimuth, altitude = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun = (math.sin(azimuth) * math.cos(altitude), math.cos(azimuth) * math.cos(altitude),
           math.sin(altitude))                                   # (east, north, up)
    shade = (sun[2] - dz_dx * sun[0] - dz_dy * sun[1]) / np.sqrt(1.0 + dz_dx**2 + dz_dy**2)
    return np.where(valid, np.clip(shade, 0.0, 1.0), np.nan)


def write_png(path, shade: np.ndarray) -> None:
    """Write a hillshade in [0, 1] as a grey PNG, NaN transparent, atomically."""
    with atomic_output(path, force=True) as tmp:
        matplotlib.image.imsave(tmp, shade, cmap="gray", vmin=0.0, vmax=1.0, format="png")


__all__ = ["hillshade", "write_png"]
