"""gfjax.pmf stage by stage against a brute-force numpy PMF (pmf_reference.py), on synthetic
scenes, and under jit / vmap / point permutations / padding."""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pmf_reference as reference
import pytest

from gfjax import pmf
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.pmf import programs, stages
from gfjax.raster import domain_mask

SHAPE = (24, 24)
CAPACITY = 2400
SMALL = pmf.Config(max_window_m=9.0)          # windows 3, 5, 9 cells


def scene(kind: str, seed: int = 0) -> np.ndarray:
    """Local float32 `(n, 3)` points on a 24 m square at 0.6 m spacing (a few empty cells).

    plane_box: flat + a 6 m x 6 m building 5 m high; ramp: 5 % slope; terrace: a 0.4 m
    step; random: noisy rough terrain with spikes (for the reference comparisons).
    """
    rng = np.random.default_rng(seed)
    g = np.arange(0.1, 23.9, 0.6)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    x = np.clip(x + rng.uniform(-0.2, 0.2, x.shape), 0.0, 23.99)
    y = np.clip(y + rng.uniform(-0.2, 0.2, y.shape), 0.0, 23.99)
    z = rng.normal(0, 0.03, x.shape)
    if kind == "plane_box":
        z = z + np.where((abs(x - 12) < 3) & (abs(y - 12) < 3), 5.0, 0.0)
    elif kind == "ramp":
        z = z + 0.05 * x
    elif kind == "terrace":
        z = z + np.where(y > 12, 0.4, 0.0)
    elif kind == "random":
        z = z + np.sin(x / 3) + rng.normal(0, 0.3, x.shape) + np.where(rng.random(x.shape) < 0.05, 8.0, 0.0)
    return np.stack([x, y, z], axis=1).astype(np.float32)


def truth(kind: str, xyz: np.ndarray) -> np.ndarray:
    if kind == "plane_box":
        return ~((abs(xyz[:, 0] - 12) < 3) & (abs(xyz[:, 1] - 12) < 3))
    return np.ones(len(xyz), bool)


def padded(xyz: np.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    buf = np.zeros((CAPACITY, 3), np.float32)
    buf[:len(xyz)] = xyz
    valid = np.zeros(CAPACITY, bool)
    valid[:len(xyz)] = True
    return jnp.asarray(buf), jnp.asarray(valid)


FULL_HW = jnp.asarray(SHAPE, jnp.int32)


def test_windows_and_thresholds():
    assert pmf.Config().windows_px == (3, 5, 9, 17, 33)
    assert pmf.Config(max_window_m=1.0).windows_px == (3,)
    assert pmf.Config(cell_m=2.0, max_window_m=33.0).windows_px == (3, 5, 9, 17)
    assert pmf.Config(exponential=False, max_window_m=9.0).windows_px == (5, 9)
    dh = stages.thresholds_m(pmf.Params(), windows_px=(3, 5, 9, 17, 33), cell_m=1.0)
    np.testing.assert_allclose(np.asarray(dh), [0.15, 2.15, 2.5, 2.5, 2.5], rtol=1e-6)
    dh = stages.thresholds_m(pmf.Params(slope=0.1), windows_px=(3, 5, 9), cell_m=2.0)
    np.testing.assert_allclose(np.asarray(dh), [0.15, 0.55, 0.95], rtol=1e-6)


DOMAINS = [("full", SHAPE), ("south_west_corner", (17, 13))]


@pytest.mark.parametrize("name,hw", DOMAINS, ids=str)
def test_stages_match_brute_force(name, hw):
    xyz = scene("random", 1)
    xyz = xyz[(xyz[:, 0] < hw[1]) & (xyz[:, 1] < hw[0])]
    buf, valid = padded(xyz)
    domain = np.asarray(domain_mask(jnp.asarray(hw, jnp.int32), SHAPE))
    zimin, filled = jax.jit(stages.minimum_surface, static_argnames=("cell_m", "shape"))(
        buf, valid, jnp.asarray(domain), cell_m=1.0, shape=SHAPE)
    ref_z, ref_filled = reference.zmin(xyz[:, :2], xyz[:, 2], SHAPE, 1.0)
    np.testing.assert_array_equal(np.asarray(filled), ref_filled & domain)
    ref_fill = reference.fill_nearest(ref_z, ref_filled & domain)
    np.testing.assert_array_equal(np.asarray(zimin)[domain], ref_fill[domain].astype(np.float32))
    opened = jax.jit(stages.progressive_openings, static_argnames="windows_px")(
        zimin, jnp.asarray(domain), windows_px=SMALL.windows_px)
    dh = np.asarray(stages.thresholds_m(pmf.Params(), windows_px=SMALL.windows_px, cell_m=1.0))
    ref_ground, ref_surfaces = reference.pmf(xyz[:, :2], xyz[:, 2], SHAPE, windows=SMALL.windows_px,
                                             thresholds=dh, domain=domain)
    for k, ref_surface in enumerate(ref_surfaces):
        np.testing.assert_array_equal(np.asarray(opened[k])[domain], ref_surface[domain].astype(np.float32))
    ground = stages.classify_points(buf, valid, opened, pmf.Params(), config=SMALL)
    np.testing.assert_array_equal(np.asarray(ground)[:len(xyz)], ref_ground)
    assert not np.asarray(ground)[len(xyz):].any()


@pytest.mark.parametrize("kind", ["plane_box", "ramp", "terrace"])
def test_scenes(kind):
    xyz = scene(kind)
    ground, diag = programs.classify_tile(*padded(xyz), FULL_HW, pmf.Params(), config=SMALL, shape=SHAPE)
    ok = np.mean(np.asarray(ground)[:len(xyz)] == truth(kind, xyz))
    assert ok > 0.95, (kind, ok)
    assert diag.zimin.shape == SHAPE


def test_jit_matches_eager():
    args = (*padded(scene("plane_box", 2)), FULL_HW, pmf.Params())
    jitted = programs.classify_tile(*args, config=SMALL, shape=SHAPE)
    with jax.disable_jit():
        eager = programs.classify_tile(*args, config=SMALL, shape=SHAPE)
    for a, b in zip(jax.tree_util.tree_leaves(jitted), jax.tree_util.tree_leaves(eager)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_vmap_matches_loop():
    scenes = [scene("plane_box", 3), scene("random", 4)]
    bufs, valids = zip(*(padded(s) for s in scenes))
    hws = jnp.stack([FULL_HW, jnp.asarray((20, 17), jnp.int32)])
    ground_b, diag_b = programs.classify_batch(jnp.stack(bufs), jnp.stack(valids), hws, pmf.Params(),
                                             config=SMALL, shape=SHAPE)
    for k in range(2):
        ground, diag = programs.classify_tile(bufs[k], valids[k], hws[k], pmf.Params(), config=SMALL, shape=SHAPE)
        np.testing.assert_array_equal(np.asarray(ground_b[k]), np.asarray(ground))
        np.testing.assert_array_equal(np.asarray(diag_b.surface[k]), np.asarray(diag.surface))


def test_point_order_does_not_matter():
    xyz = scene("random", 5)
    perm = np.random.default_rng(0).permutation(len(xyz))
    a, _ = programs.classify_tile(*padded(xyz), FULL_HW, pmf.Params(), config=SMALL, shape=SHAPE)
    b, _ = programs.classify_tile(*padded(xyz[perm]), FULL_HW, pmf.Params(), config=SMALL, shape=SHAPE)
    np.testing.assert_array_equal(np.asarray(a)[:len(xyz)][perm], np.asarray(b)[:len(xyz)])


def test_filter_on_cloud():
    xyz = scene("plane_box", 6).astype(np.float64) + np.array([5e5, 4e6, 100.0])
    cls = np.zeros(len(xyz), np.uint8)
    cls[:10] = 18                                        # high noise: never ground
    cloud = Cloud.from_xyz(xyz, classification=cls)
    result = pmf.filter(cloud, config=SMALL)
    assert not result.ground[:10].any()
    assert np.mean(result.ground[10:] == truth("plane_box", xyz - xyz.min(axis=0))[10:]) > 0.95
    assert result.diagnostics.windows_px == (3, 5, 9)
    with pytest.raises(InputError, match="slope"):
        pmf.filter(cloud, params=pmf.Params(slope=-1.0))
    with pytest.raises(ValueError, match="max_window_m"):
        pmf.Config(max_window_m=0.0)
    with pytest.raises(ValueError, match="base"):
        dataclasses.replace(SMALL, base=1)
