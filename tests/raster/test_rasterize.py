"""Cell-index convention, rasterisation (vs a Python loop) and bilinear sampling (vs scipy)."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference

from gfjax import raster

SHAPE = (12, 9)
CELL_M = 0.5


def _points(n: int, seed: int):
    """Points over and around a 12 x 9 raster of 0.5 m cells, with duplicates and ties."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.6, 5.1, size=(n, 2)).astype(np.float32)
    xy[:, 1] *= SHAPE[0] * CELL_M / (SHAPE[1] * CELL_M)
    xy[: n // 8] = xy[n // 8: 2 * (n // 8)]                               # duplicate points
    z = (np.round(rng.normal(50, 2, size=n) * 2) / 2).astype(np.float32)  # ties
    z[3] = np.nan
    valid = rng.random(n) < 0.9
    return xy, z, valid


@functools.cache
def jitted():
    return jax.jit(functools.partial(raster.rasterize, cell_m=CELL_M, shape=SHAPE))


def test_cell_index_convention_row0_is_north():
    h, w = SHAPE
    xy = jnp.asarray([[0.1, h * CELL_M - 0.1],       # north-west corner cell
                      [w * CELL_M - 0.1, 0.1],       # south-east corner cell
                      [w * CELL_M, 0.1],             # on the east edge: outside
                      [0.1, -0.01],                  # south of the raster
                      [np.nan, 1.0]], jnp.float32)
    row, col, inside = raster.cell_index(xy, cell_m=CELL_M, shape=SHAPE)
    np.testing.assert_array_equal(np.asarray(row)[:2], [0, h - 1])
    np.testing.assert_array_equal(np.asarray(col)[:2], [0, w - 1])
    np.testing.assert_array_equal(np.asarray(inside), [True, True, False, False, False])


@pytest.mark.parametrize("n", [1, 400])
def test_rasterize_matches_loop(n):
    xy, z, valid = _points(max(n, 8), seed=n)
    xy, z, valid = xy[:n], z[:n], valid[:n]
    stats = jitted()(xy, z, valid)
    want = reference.rasterize(xy, z, valid, CELL_M, SHAPE)
    for key in ("z_min", "z_max", "count", "argmin", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(stats, key)), want[key], err_msg=key)
    np.testing.assert_allclose(np.asarray(stats.z_mean), want["z_mean"], rtol=1e-6)


def test_rasterize_empty_and_order_invariant():
    xy, z, valid = _points(400, seed=3)
    empty = jitted()(xy, z, np.zeros_like(valid))
    assert not bool(empty.valid.any()) and bool(jnp.all(empty.argmin == -1))
    assert bool(jnp.all(empty.z_min == jnp.inf)) and bool(jnp.all(empty.z_max == -jnp.inf))
    perm = np.random.default_rng(0).permutation(len(z))
    a, b = jitted()(xy, z, valid), jitted()(xy[perm], z[perm], valid[perm])
    for key in ("z_min", "z_max", "count", "valid"):
        np.testing.assert_array_equal(np.asarray(getattr(a, key)), np.asarray(getattr(b, key)))
    # the lowest point found is the same point (up to equal-z ties)
    np.testing.assert_array_equal(z[np.asarray(a.argmin)[np.asarray(a.valid)]],
                                  z[perm][np.asarray(b.argmin)[np.asarray(b.valid)]])


def test_rasterize_jit_eager_vmap():
    inputs = [_points(400, seed=s) for s in range(3)]
    eager = raster.rasterize(*map(jnp.asarray, inputs[0]), cell_m=CELL_M, shape=SHAPE)
    for got, want in zip(jitted()(*inputs[0]), eager):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    batched = jax.jit(jax.vmap(jitted()))(*(np.stack(x) for x in zip(*inputs)))
    for b in range(3):
        for got, want in zip(batched, jitted()(*inputs[b])):
            np.testing.assert_array_equal(np.asarray(got[b]), np.asarray(want))


@pytest.mark.parametrize("shape", [(12, 9), (1, 5), (1, 1)])
def test_bilinear_matches_scipy(shape):
    rng = np.random.default_rng(4)
    z = rng.normal(size=shape).astype(np.float32)
    h, w = shape
    xy = np.stack([rng.uniform(-1, w * CELL_M + 1, 300), rng.uniform(-1, h * CELL_M + 1, 300)], 1).astype(np.float32)
    fn = jax.jit(functools.partial(raster.sample_bilinear, cell_m=CELL_M))
    np.testing.assert_allclose(np.asarray(fn(z, xy)), reference.bilinear(z, xy, CELL_M), rtol=1e-5, atol=1e-5)
    centres = np.stack(np.meshgrid((np.arange(w) + 0.5) * CELL_M, (h - 1 - np.arange(h) + 0.5) * CELL_M), -1)
    np.testing.assert_array_equal(np.asarray(fn(z, centres.reshape(-1, 2).astype(np.float32))), z.ravel())
    batched = jax.vmap(fn)(np.stack([z, 2 * z]), np.stack([xy, xy]))
    np.testing.assert_array_equal(np.asarray(batched[1]), np.asarray(fn(2 * z, xy)))
