"""The speed paths of DMF pinned to their reference paths: the running-minimum nearest ND_CE
against `argmin`, and the whole filter with the bucket-grid cylinder table against the KD-tree
table (labels, basal layer, iterations)."""
from __future__ import annotations

import functools
from unittest import mock

import dmf_scenes as scenes
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import dmf
from gfjax.dmf import basal, neighbours


def _table(seed: int, m: int = 40, k: int = 16):
    """A random neighbour table with many exact distance ties (quantised values)."""
    rng = np.random.default_rng(seed)
    z = np.round(rng.uniform(0, 4, m), 1).astype(np.float32)
    z0 = np.round(rng.uniform(0, 4, m), 1).astype(np.float32)
    dxy2 = np.round(rng.uniform(0, 9, (m, k)), 0).astype(np.float32)
    index = rng.integers(0, m, (m, k)).astype(np.int32)
    valid = rng.random((m, k)) < 0.7
    valid[0] = False                                       # a node with no neighbour: slot 0
    return z, z0, dxy2, index, valid


def _argmin_reference(z, z0, dxy2, index, valid):
    """`np.argmin` (first minimum) over each row of the masked 3D squared distances."""
    d2 = np.where(valid, dxy2 + (z0[index] - z[:, None]) ** 2, np.float32(np.inf))
    return index[np.arange(len(z)), np.argmin(d2, axis=1)]


@pytest.fixture(scope="session")
def jit_nearest():
    return jax.jit(basal.nearest_in_table)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nearest_in_table_matches_argmin(jit_nearest, seed):
    args = _table(seed)
    expected = _argmin_reference(*args)
    np.testing.assert_array_equal(np.asarray(jit_nearest(*map(jnp.asarray, args))), expected)


def test_nearest_in_table_under_vmap(jit_nearest):
    tables = [_table(seed) for seed in (3, 4)]
    stacked = [jnp.asarray(np.stack(parts)) for parts in zip(*tables)]
    out = jax.jit(jax.vmap(basal.nearest_in_table))(*stacked)
    for i, args in enumerate(tables):
        np.testing.assert_array_equal(np.asarray(out[i]), _argmin_reference(*args))


@pytest.fixture(scope="session")
def box_cloud():
    return scenes.box_scene()[0]


@pytest.mark.parametrize("preset", [None, "paper"])
def test_filter_speed_path_equals_the_kdtree_path(box_cloud, preset):
    config = dmf.Config(**dmf.PRESETS[preset]) if preset else dmf.Config()
    fast = dmf.filter(box_cloud, config=config)
    with mock.patch.object(neighbours, "cylinder_table", functools.partial(neighbours.cylinder_table, method="kdtree")):
        reference = dmf.filter(box_cloud, config=config)
    np.testing.assert_array_equal(fast.ground, reference.ground)
    np.testing.assert_array_equal(fast.instance_id, reference.instance_id)
    np.testing.assert_array_equal(fast.diagnostics.basal_z, reference.diagnostics.basal_z)
    assert fast.diagnostics.basal_iterations == reference.diagnostics.basal_iterations
