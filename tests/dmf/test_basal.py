"""DMF step 3: the basal-layer loop against a plain numpy loop; its sorting network and median."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.dmf import basal, neighbours


@pytest.fixture(scope="session")
def jit_sort():
    return jax.jit(basal.sort_rows)


@pytest.mark.parametrize("width", [8, 32])
def test_sort_rows_matches_numpy(jit_sort, width):
    rng = np.random.default_rng(width)
    x = rng.normal(size=(37, width)).astype(np.float32)
    x[rng.random(x.shape) < 0.3] = np.inf
    x[:, 0] = x[:, 1]                                        # ties
    np.testing.assert_array_equal(np.asarray(jit_sort(jnp.asarray(x))), np.sort(x, axis=1))
    if width == 8:                                           # eager too (slow op by op)
        np.testing.assert_array_equal(np.asarray(basal.sort_rows(jnp.asarray(x))), np.sort(x, axis=1))


def test_sort_rows_rejects_odd_width():
    with pytest.raises(ValueError, match="power-of-two"):
        basal.sort_rows(jnp.zeros((2, 6)))


def test_masked_median_matches_numpy():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(50, 16)).astype(np.float32)
    use = rng.random(x.shape) < 0.5
    use[0] = False
    med, count = jax.jit(basal.masked_median)(jnp.asarray(x), jnp.asarray(use))
    for i in range(len(x)):
        expected = np.median(x[i][use[i]]) if use[i].any() else np.inf
        np.testing.assert_allclose(float(med[i]), expected, rtol=1e-6)
        assert int(count[i]) == use[i].sum()


def _reference(xyz, index, valid, cap_m, stop, max_iter):
    """The loop of Sec. 2.3 written plainly, node by node."""
    z0 = xyz[:, 2].astype(np.float64)
    z = z0.copy()
    m = len(z)

    def nearest(zc):
        out = np.empty(m, int)
        for i in range(m):
            best, arg = np.inf, -1
            for j, ok in zip(index[i], valid[i]):
                if ok:
                    d2 = np.sum((xyz[i, :2] - xyz[j, :2]) ** 2) + (z0[j] - zc[i]) ** 2
                    if d2 < best:
                        best, arg = d2, j
            out[i] = arg
        return out

    nn = nearest(z)
    frozen = np.zeros(m, bool)
    for it in range(1, max_iter + 1):
        new = z.copy()
        for i in range(m):
            if frozen[i]:
                continue
            lower = [z[j] for j, ok in zip(index[i], valid[i]) if ok and z[j] < z[i]]
            if lower:
                new[i] = max(np.median(lower), z0[i] - cap_m)
        z = new
        nn_new = nearest(z)
        same = nn_new == nn
        nn = nn_new
        if stop == "per_node":
            frozen |= same
            if frozen.all():
                return z, nn, it, True
        elif same.all():
            return z, nn, it, True
    return z, nn, max_iter, False


@pytest.mark.parametrize("stop,cap_m", [("global", np.inf), ("per_node", np.inf), ("global", 1.5)])
def test_basal_layer_matches_reference(stop, cap_m):
    rng = np.random.default_rng(7)
    gx, gy = np.meshgrid(np.arange(8.0), np.arange(7.0))
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1) + rng.uniform(0.1, 0.9, (56, 2))
    z = 0.1 * xy[:, 0] + rng.normal(0, 0.05, 56)
    z[rng.choice(56, 10, replace=False)] += rng.uniform(2, 9, 10)          # "canopy" centroids
    xyz = np.column_stack([xy, z]).astype(np.float32)
    table = neighbours.cylinder_table(xyz[:, :2].astype(np.float64), radius_m=2.0, k=25)
    out = basal.basal_layer(jnp.asarray(xyz), jnp.asarray(table.index), jnp.asarray(table.valid),
                            jnp.float32(cap_m), stop=stop, max_iter=50)
    z_ref, nn_ref, it_ref, conv_ref = _reference(xyz.astype(np.float64), table.index, table.valid, cap_m, stop, 50)
    np.testing.assert_allclose(np.asarray(out.z), z_ref, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(np.asarray(out.nearest), nn_ref)
    assert int(out.iterations) == it_ref and bool(out.converged) == conv_ref
    assert np.all(np.asarray(out.z) <= xyz[:, 2])
    assert np.all(np.asarray(out.z) >= xyz[:, 2] - cap_m - 1e-5)


def test_basal_layer_reports_cap_on_iterations():
    xyz = np.array([[0, 0, 0], [1, 0, 5], [2, 0, 10], [3, 0, 15]], np.float32)
    table = neighbours.cylinder_table(xyz[:, :2].astype(np.float64), radius_m=3.5, k=16)
    out = basal.basal_layer(jnp.asarray(xyz), jnp.asarray(table.index), jnp.asarray(table.valid),
                            jnp.float32(np.inf), stop="global", max_iter=1)
    assert int(out.iterations) == 1 and not bool(out.converged)


@pytest.mark.parametrize("stop", ["global", "per_node"])
def test_padding_to_a_canonical_shape_leaves_the_basal_layer_as_it_is(stop):
    """`dmf.filter` pads the nodes to a power-of-two capacity and the table to its full width:
    the real nodes' layer, nearest nodes and iteration count are the unpadded ones."""
    from gfjax.dmf.filter import _padded_nodes

    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 12, (150, 2))
    xyz = np.column_stack([xy, 0.2 * xy[:, 1] + rng.uniform(0, 3, 150) ** 3]).astype(np.float32)
    table = neighbours.cylinder_table(xy, radius_m=2.5, k=49, max_width=32)
    plain = basal.basal_layer(xyz, table.index, table.valid, np.float32(np.inf), stop=stop, max_iter=60)
    xyz_p, index_p, valid_p = _padded_nodes(xyz, table, 32)
    assert xyz_p.shape == (4096, 3) and index_p.shape == valid_p.shape == (4096, 32)
    padded = basal.basal_layer(xyz_p, index_p, valid_p, np.float32(np.inf), stop=stop, max_iter=60)
    np.testing.assert_array_equal(np.asarray(padded.z)[:150], np.asarray(plain.z))
    np.testing.assert_array_equal(np.asarray(padded.nearest)[:150], np.asarray(plain.nearest))
    assert int(padded.iterations) == int(plain.iterations) and bool(padded.converged) == bool(plain.converged)
