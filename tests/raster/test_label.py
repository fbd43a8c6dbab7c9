"""Connected components (as partitions vs scipy.ndimage.label), relabelling, ring stats."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
import scipy.ndimage as ndi

from gfjax import raster


def _checkerboard(h, w):
    return (np.add.outer(np.arange(h), np.arange(w)) % 2) == 0


def _spiral(n):
    """A one-cell-wide spiral: one component of long graph diameter."""
    m = np.zeros((n, n), bool)
    top, left, bottom, right = 0, 0, n - 1, n - 1
    while top <= bottom and left <= right:
        m[top, left:right + 1] = True
        m[top:bottom + 1, right] = True
        m[bottom, left:right + 1] = True
        m[top + 2:bottom + 1, left] = True
        if top + 2 <= bottom:
            m[top + 2, left:right - 1] = True
        top, left, bottom, right = top + 2, left + 2, bottom - 2, right - 2
    return m


def _random(shape, p, seed):
    return np.random.default_rng(seed).random(shape) < p


MASKS = {
    "random_sparse": _random((32, 24), 0.45, 0),
    "random_dense": _random((32, 24), 0.62, 1),
    "checkerboard": _checkerboard(16, 16),
    "all_empty": np.zeros((8, 8), bool),
    "all_full": np.ones((8, 8), bool),
    "one_row": _random((1, 33), 0.6, 2),
    "one_column": _random((33, 1), 0.6, 3),
    "one_cell": np.ones((1, 1), bool),
    "spiral": _spiral(32),
    "u_shapes": np.array([[1, 0, 1, 0, 1, 1], [1, 0, 1, 0, 0, 1], [1, 1, 1, 0, 1, 1], [0, 0, 0, 1, 0, 0]], bool),
}


@functools.cache
def jitted(connectivity: int):
    def fn(mask):
        labels, converged = raster.label_components(mask, connectivity=connectivity)
        consecutive, n = raster.relabel_consecutive(labels)
        return labels, converged, consecutive, n
    return jax.jit(fn)


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("name", MASKS)
def test_labels_match_scipy_as_partitions(name, connectivity):
    mask = MASKS[name]
    expected, n_expected = ndi.label(mask, reference.structure(connectivity))
    labels, converged, consecutive, n = jitted(connectivity)(mask)
    assert bool(converged)
    labels = np.asarray(labels)
    assert np.all((labels > 0) == mask)
    np.testing.assert_array_equal(reference.canonical_labels(labels), reference.canonical_labels(expected))
    # relabel_consecutive: ids 1..n in raster first-occurrence order, as canonical_labels.
    np.testing.assert_array_equal(np.asarray(consecutive), reference.canonical_labels(expected))
    assert int(n) == n_expected


def test_checkerboard_connectivity():
    mask = MASKS["checkerboard"]
    assert int(jitted(4)(mask)[3]) == mask.sum()          # every cell alone
    assert int(jitted(8)(mask)[3]) == 1                   # corners join all of them


def test_iteration_cap_reports_not_converged():
    mask = MASKS["spiral"]
    _, converged = jax.jit(functools.partial(raster.label_components, connectivity=4, max_iter=1))(mask)
    assert not bool(converged)


@pytest.mark.parametrize("name", ["random_sparse", "spiral", "one_row"])
def test_jit_equals_eager(name):
    mask = jnp.asarray(MASKS[name])
    eager_labels, eager_converged = raster.label_components(mask, connectivity=8)
    labels, converged, _, _ = jitted(8)(mask)
    np.testing.assert_array_equal(np.asarray(labels), np.asarray(eager_labels))
    assert bool(converged) == bool(eager_converged)


@pytest.mark.parametrize("connectivity", [4, 8])
def test_vmap_equals_loop(connectivity):
    masks = np.stack([MASKS["random_sparse"], MASKS["random_dense"], _random((32, 24), 0.5, 9)])
    fn = jitted(connectivity)
    batched = jax.jit(jax.vmap(fn))(masks)
    for b in range(len(masks)):
        for got, want in zip(batched, fn(masks[b])):
            np.testing.assert_array_equal(np.asarray(got[b]), np.asarray(want))


def test_padding_never_changes_partition():
    mask = MASKS["random_dense"]
    padded = np.zeros((40, 40), bool)
    padded[:32, :24] = mask
    small = reference.canonical_labels(np.asarray(jitted(8)(mask)[0]))
    big = reference.canonical_labels(np.asarray(jitted(8)(padded)[0]))
    np.testing.assert_array_equal(big[:32, :24], small)


NUM_LABELS = 40


@functools.cache
def jitted_stats(connectivity: int):
    def fn(labels, values, valid):
        return raster.boundary_ring(labels, values, valid, num_labels=NUM_LABELS, connectivity=connectivity)
    return jax.jit(fn)


def _stats_input(seed: int):
    rng = np.random.default_rng(seed)
    mask = rng.random((24, 20)) < 0.55
    labels, _ = ndi.label(mask, reference.structure(8))
    labels = labels.astype(np.int32)
    values = (np.round(rng.normal(10, 3, size=(24, 20)) * 4) / 4).astype(np.float32)
    valid = rng.random((24, 20)) < 0.8
    return labels, values, valid


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("seed", [0, 1])
def test_ring_stats_match_reference(seed, connectivity):
    labels, values, valid = _stats_input(seed)
    assert labels.max() <= NUM_LABELS
    ring = jitted_stats(connectivity)(labels, values, valid)
    count, vcount, vmin, vmax, mean = reference.ring_stats(labels, values, valid, connectivity, NUM_LABELS)
    np.testing.assert_array_equal(np.asarray(ring.count)[1:], count[1:])
    np.testing.assert_array_equal(np.asarray(ring.valid_count)[1:], vcount[1:])
    np.testing.assert_array_equal(np.asarray(ring.min)[1:], vmin[1:])
    np.testing.assert_array_equal(np.asarray(ring.max)[1:], vmax[1:])
    np.testing.assert_allclose(np.asarray(ring.mean)[1:], mean[1:], rtol=1e-6)


def test_rings_of_touching_labels_overlap_exactly():
    """Two labels side by side (4-connected mask of two ids): each is on the other's ring."""
    labels = np.zeros((5, 6), np.int32)
    labels[1:4, 1:3] = 1
    labels[1:4, 3:5] = 2
    values = np.arange(30, dtype=np.float32).reshape(5, 6)
    ring = raster.boundary_ring(jnp.asarray(labels), jnp.asarray(values), num_labels=2, connectivity=8)
    count, _, vmin, vmax, _ = reference.ring_stats(labels, values, np.ones((5, 6), bool), 8, 2)
    np.testing.assert_array_equal(np.asarray(ring.count)[1:], count[1:])
    np.testing.assert_array_equal(np.asarray(ring.max)[1:], vmax[1:])
    np.testing.assert_array_equal(np.asarray(ring.min)[1:], vmin[1:])
    # By hand: each ring is its 3x3 dilation (5 x 4 cells) minus its 6 cells, the other
    # label's touching column included; label 1's ring reaches cell (4, 3) = 27.
    assert int(ring.count[1]) == 14 and int(ring.count[2]) == 14
    assert float(ring.max[1]) == 27.0 and float(ring.min[2]) == 2.0


def test_stats_jit_eager_and_vmap():
    inputs = [_stats_input(s) for s in range(3)]
    fn = jitted_stats(8)
    eager = raster.boundary_ring(*map(jnp.asarray, inputs[0]), num_labels=NUM_LABELS, connectivity=8)
    for got, want in zip(jax.tree.leaves(fn(*inputs[0])), jax.tree.leaves(eager)):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    stacked = [np.stack(x) for x in zip(*inputs)]
    batched = jax.jit(jax.vmap(fn))(*stacked)
    for b in range(3):
        for got, want in zip(jax.tree.leaves(batched), jax.tree.leaves(fn(*inputs[b]))):
            np.testing.assert_array_equal(np.asarray(got[b]), np.asarray(want))


def test_bad_connectivity():
    with pytest.raises(ValueError, match="connectivity"):
        raster.label_components(jnp.zeros((3, 3), bool), connectivity=6)
