"""DMF raster stages (steps 4-6): references, jit, padding invariance and vmap over tiles."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage as ndi

from gfjax import raster
from gfjax.dmf import Config, stages
from gfjax.dmf.config import MAX_BATCH
from gfjax.dmf.programs import batched_stages, stage_options

TILE = (40, 44)
PADDED = (48, 48)        # padded batch of MAX_BATCH: the compile is shared with the tiled filter test
CELL_M = 1.0


def ngnem_tile(seed: int, *, border_box: bool = False, empty: float = 0.05):
    """A sloping ground (5 cm per cell) with boxes 4-7 m high; optionally one cut by the
    north border. Returns `(z, layer, valid)` of shape TILE."""
    rng = np.random.default_rng(seed)
    h, w = TILE
    z = 0.05 * np.arange(w)[None, :] + np.zeros((h, 1)) + rng.normal(0, 0.02, (h, w))
    r0, c0 = rng.integers(12, 30), rng.integers(4, 24)
    z[r0:r0 + 9, c0:c0 + 12] += rng.uniform(4, 7)
    z[4:9, 30:40] += 3.0                                                       # a small box
    if border_box:
        z[0:5, 10:18] += 6.0
    valid = rng.random((h, w)) > empty
    return z.astype(np.float32), np.floor(z / CELL_M).astype(np.int32), valid


def pad_tile(z, layer, valid, shape=PADDED):
    pad = ((0, shape[0] - z.shape[0]), (0, shape[1] - z.shape[1]))
    inside = np.pad(np.ones(z.shape, bool), pad)
    return (jnp.asarray(np.pad(z, pad)), jnp.asarray(np.pad(layer, pad)), jnp.asarray(np.pad(valid, pad)),
            jnp.asarray(inside))


@pytest.fixture(scope="session")
def run_tile():
    options = stage_options(Config())                 # as the filter calls it: one shared compile
    return lambda z, k, v, inside: stages.raster_stages(z, k, v, inside, jnp.float32(CELL_M), jnp.float32(1.0), **options)


@pytest.fixture(scope="session")
def unpadded_results(run_tile):
    tiles = [ngnem_tile(s, border_box=(s == 1)) for s in range(3)]
    return tiles, [run_tile(jnp.asarray(z), jnp.asarray(k), jnp.asarray(v), jnp.ones(TILE, bool)) for z, k, v in tiles]


def test_boxes_are_objects_and_the_slope_is_not(unpadded_results):
    tiles, results = unpadded_results
    for (z, _, valid), out in zip(tiles, results):
        base = 0.05 * np.arange(TILE[1])[None, :]
        high = (z - base > 2.0) & valid
        rc = np.asarray(out.ngnem_rc)
        assert rc[high].mean() > 0.9                                # box cells: objects
        assert not rc[(z - base < 0.5) & valid].any()               # ground cells: never
        assert bool(out.converged)
        inst = np.asarray(out.instances)
        assert inst.max() >= 2 and set(np.unique(inst[rc])) == set(range(1, inst.max() + 1))


def test_box_cut_by_border_is_object(unpadded_results):
    _, results = unpadded_results
    assert np.asarray(results[1].ngnem_bi)[0:5, 10:18].all()
    assert np.asarray(results[1].ngnem_rc)[0:5, 10:18].all()


def test_vmap_over_padded_tiles_equals_tile_by_tile(unpadded_results):
    """A batch of tiles padded to one shape, under vmap, gives each unpadded tile's rasters on
    its inside cells (so padding changes nothing, and batching changes nothing)."""
    tiles, results = unpadded_results
    padded = [pad_tile(*t) for t in tiles]
    padded += [padded[-1]] * (MAX_BATCH - len(padded))          # the filter's batch shape: shared compile
    batch = [jnp.stack(parts) for parts in zip(*padded)]
    out = batched_stages(*batch, jnp.float32(CELL_M), jnp.float32(1.0), **stage_options(Config()))
    h, w = TILE
    for b, single in enumerate(results):
        for name in ("ngnem", "layer", "rhc", "ngnem_bi", "ngnem_rc0", "ngnem_rc", "instances"):
            np.testing.assert_array_equal(np.asarray(getattr(out, name))[b, :h, :w], np.asarray(getattr(single, name)),
                                          err_msg=f"tile {b} {name}")


def test_rhc_matches_scipy():
    z, _, _ = ngnem_tile(4)
    got = jax.jit(functools.partial(stages.rhc, radius_px=2))(jnp.asarray(z), jnp.ones(TILE, bool), jnp.float32(CELL_M))
    expected = ndi.maximum_filter(z, size=5, mode="constant", cval=-np.inf) - z > CELL_M
    np.testing.assert_array_equal(np.asarray(got), expected)


@pytest.fixture(scope="session")
def jit_closing():
    return jax.jit(functools.partial(stages.closing_square, max_radius_px=4))


@pytest.mark.parametrize("radius", [1, 2, 4])
@pytest.mark.parametrize("seed", [0, 1])
def test_closing_square_matches_raster_closing(jit_closing, radius, seed):
    rng = np.random.default_rng(seed)
    mask = rng.random((20, 23)) < 0.25
    inside = np.zeros((20, 23), bool)
    inside[:17, :19] = True
    got = jit_closing(jnp.asarray(mask), jnp.asarray(inside), jnp.int32(radius))
    expected = raster.closing(jnp.asarray(mask & inside).astype(jnp.uint8), jnp.asarray(inside),
                              radius_px=radius, footprint="square") > 0
    np.testing.assert_array_equal(np.asarray(got), np.asarray(expected) & inside)
    assert np.all(np.asarray(got)[mask & inside])                  # extensive


def _canonical(labels):
    _, first = np.unique(labels.ravel(), return_index=True)
    order = {lab: i for i, lab in enumerate(labels.ravel()[np.sort(first)])}
    return np.vectorize(order.get)(labels)


def test_equal_layer_regions_match_scipy_per_value():
    rng = np.random.default_rng(3)
    layer = rng.integers(0, 3, (18, 21)).astype(np.int32)
    inside = np.ones_like(layer, bool)
    inside[:, 19:] = False
    got, conv = jax.jit(stages.equal_layer_regions)(jnp.asarray(layer), jnp.asarray(inside))
    expected = np.zeros(layer.shape, int)
    offset = 0
    for value in np.unique(layer):
        lab, n = ndi.label((layer == value) & inside)
        expected[lab > 0] = lab[lab > 0] + offset
        offset += n
    assert bool(conv)
    np.testing.assert_array_equal(_canonical(np.asarray(got)), _canonical(expected))
    got = np.asarray(got)
    for lab in np.unique(got[got > 0]):                  # id = 1 + the row-major index of the first cell
        assert lab == 1 + np.flatnonzero(got.ravel() == lab)[0]
    assert got.max() <= layer.size


def test_the_equal_layer_correction_applies_all_over_the_raster():
    """(a) resets a BI region's cells whose equal-layer region is not wholly in NGNEM_BI, in the
    last rows of a raster as in its first (region ids must index the per-region sums)."""
    h, w = 24, 20
    layer = np.zeros((h, w), np.int32)
    bi = np.zeros((h, w), bool)
    for r0 in (1, h - 5):                                # a block at the top and one at the bottom
        layer[r0:r0 + 4, 3:9] = 1                        # a region of layer 1, 4 x 6 cells ...
        bi[r0:r0 + 4, 3:8] = True                        # ... of which NGNEM_BI covers all but a column
        layer[r0:r0 + 3, 12:16] = 2                      # a region wholly in NGNEM_BI
        bi[r0:r0 + 3, 12:16] = True
    ngnem = np.where(layer > 0, 5.0, 0.0).astype(np.float32)
    inside = np.ones((h, w), bool)
    rc0, _, _, conv = stages.patch_correction(jnp.asarray(ngnem), jnp.asarray(layer), jnp.asarray(bi),
                                              jnp.asarray(inside))
    rc0 = np.asarray(rc0)
    assert bool(conv)
    np.testing.assert_array_equal(rc0, bi & (layer == 2))
