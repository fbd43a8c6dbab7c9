"""Hillshade: flat and tilted planes against the analytic illumination, Horn's kernel, nodata."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage as ndi

from gfjax.dtm.hillshade import hillshade


def _plane(shape, cell, slope_east, slope_north):
    h, w = shape
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    x, y = (cols + 0.5) * cell, (h - 1 - rows + 0.5) * cell          # row 0 = north
    return 100.0 + slope_east * x + slope_north * y


def _analytic(slope_east, slope_north, azimuth_deg, altitude_deg):
    """Cosine between the plane's unit normal and the unit vector to the sun."""
    a, h = math.radians(azimuth_deg), math.radians(altitude_deg)
    normal = np.array([-slope_east, -slope_north, 1.0]) / math.hypot(slope_east, slope_north, 1.0)
    sun = np.array([math.sin(a) * math.cos(h), math.cos(a) * math.cos(h), math.sin(h)])
    return max(float(normal @ sun), 0.0)


@pytest.mark.parametrize("altitude_deg", [45.0, 30.0, 90.0])
def test_flat_plane_is_constant(altitude_deg):
    z = np.full((16, 20), 123.4)
    shade = hillshade(z, np.ones(z.shape, bool), cell=2.0, altitude_deg=altitude_deg)
    np.testing.assert_allclose(shade, math.sin(math.radians(altitude_deg)), rtol=0, atol=1e-12)


@pytest.mark.parametrize("slope_east,slope_north,azimuth_deg,altitude_deg",
                         [(0.5, 0.0, 315.0, 45.0), (-0.5, 0.0, 270.0, 45.0), (0.0, 0.8, 180.0, 30.0),
                          (0.3, -0.4, 45.0, 60.0), (2.0, 0.0, 90.0, 20.0)])
def test_tilted_plane_matches_analytic(slope_east, slope_north, azimuth_deg, altitude_deg):
    z = _plane((12, 14), 1.5, slope_east, slope_north)
    shade = hillshade(z, np.ones(z.shape, bool), cell=1.5, azimuth_deg=azimuth_deg,
                      altitude_deg=altitude_deg)
    expected = _analytic(slope_east, slope_north, azimuth_deg, altitude_deg)
    np.testing.assert_allclose(shade[1:-1, 1:-1], expected, rtol=0, atol=1e-12)


def test_z_factor_feet_over_metres():
    """x, y in feet, z in metres: a 1 m rise over 1 m run is the same slope as in metres."""
    z_m = _plane((8, 8), 1.0 / 0.3048, 0.3048, 0.0)       # rises 0.3048 m per foot east = 1 m/m
    shade = hillshade(z_m, np.ones(z_m.shape, bool), cell=1.0 / 0.3048, z_factor=1.0 / 0.3048,
                      azimuth_deg=270.0)
    np.testing.assert_allclose(shade[1:-1, 1:-1], _analytic(1.0, 0.0, 270.0, 45.0), atol=1e-12)


def test_random_surface_matches_horn_kernels():
    rng = np.random.default_rng(0)
    z = ndi.gaussian_filter(rng.normal(size=(24, 30)), 2.0) * 20.0
    cell, azimuth, altitude = 2.0, 315.0, 45.0
    # GDAL's gdaldem hillshade, literally: x east, y *south* (dz/dy = south row - north row)
    horn_x = np.array([[-1, 0, 1], [-2, 0, 2], [-1, 0, 1]]) / (8 * cell)
    horn_y = np.array([[-1, -2, -1], [0, 0, 0], [1, 2, 1]]) / (8 * cell)
    dx, dy = ndi.correlate(z, horn_x), ndi.correlate(z, horn_y)
    zenith, azimuth_math = math.radians(90.0 - altitude), math.radians(360.0 - azimuth + 90.0)
    slope = np.arctan(np.hypot(dx, dy))
    aspect = np.arctan2(dy, -dx)
    expected = np.clip(math.cos(zenith) * np.cos(slope)
                       + math.sin(zenith) * np.sin(slope) * np.cos(azimuth_math - aspect), 0, 1)
    got = hillshade(z, np.ones(z.shape, bool), cell=cell, azimuth_deg=azimuth, altitude_deg=altitude)
    np.testing.assert_allclose(got[1:-1, 1:-1], expected[1:-1, 1:-1], rtol=0, atol=1e-12)
    assert got.std() > 0.05


def test_nodata_is_nan_and_ignored():
    z = _plane((10, 10), 1.0, 0.5, 0.0)
    valid = np.ones(z.shape, bool)
    valid[4:6, 4:6] = False
    z_holed = np.where(valid, z, -9999.0)
    shade = hillshade(z_holed, valid, cell=1.0, azimuth_deg=270.0)
    assert np.all(np.isnan(shade[~valid])) and np.all(np.isfinite(shade[valid]))
    assert np.all((shade[valid] >= 0) & (shade[valid] <= 1))
    # a neighbour without a value never drags the slope to -9999: the shade stays near the
    # plane's (one-sided differences halve one term of Horn's sum at worst)
    expected = _analytic(0.5, 0.0, 270.0, 45.0)
    flat = math.sin(math.radians(45.0))
    assert np.all(np.abs(shade[valid] - expected) <= abs(expected - flat) + 1e-12)
