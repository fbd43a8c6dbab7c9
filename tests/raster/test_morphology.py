"""Grey morphology: exactly scipy.ndimage (floats included), under jit and vmap."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import reference
import scipy.ndimage as ndi
import skimage.morphology
from reference import Case

from gfjax import raster

CASES = [
    Case("random", (32, 24), radius=3),
    Case("random_big_radius", (40, 40), radius=18),
    Case("all_empty", (8, 8), radius=2, valid_fraction=0.0),
    Case("all_full", (16, 16), radius=4, valid_fraction=1.0),
    Case("one_row", (1, 33), radius=4),
    Case("one_cell", (1, 1), radius=1, valid_fraction=1.0),
    Case("radius_exceeds_tile", (5, 5), radius=9),
    Case("sparse", (32, 24), radius=1, valid_fraction=0.1),
]
FOOTPRINTS = ["disk", "square"]
OPS = {"min_filter": reference.erosion, "max_filter": reference.dilation,
       "opening": reference.opening, "closing": reference.closing}


@functools.cache
def jitted(op: str, radius: int, footprint: str):
    fn = getattr(raster, op)
    return jax.jit(lambda z, valid: fn(z, valid, radius_px=radius, footprint=footprint))


@functools.cache
def jitted_all(radius: int, footprint: str, ops: tuple[str, ...] = tuple(OPS), **kwargs):
    """One compile for several ops (keeps the number of compiles small)."""
    fns = [functools.partial(getattr(raster, op), radius_px=radius, footprint=footprint, **kwargs) for op in ops]
    return jax.jit(lambda *args: [fn(*args) for fn in fns])


@pytest.mark.parametrize("radius", [0, 1, 2, 5, 18, 25])
def test_disk_equals_skimage(radius):
    np.testing.assert_array_equal(raster.disk(radius), skimage.morphology.disk(radius).astype(bool))
    chords = raster.chord_half_widths(radius)
    rows = raster.disk(radius).sum(axis=1)
    np.testing.assert_array_equal(2 * np.asarray(chords) + 1, rows)


@pytest.mark.parametrize("footprint", FOOTPRINTS)
@pytest.mark.parametrize("op", OPS)
@pytest.mark.parametrize("case", CASES, ids=str)
def test_matches_scipy_exactly(case, op, footprint):
    z, valid = reference.random_raster(case, seed=1)
    got = jitted_all(case.radius, footprint)(z, valid)[list(OPS).index(op)]
    np.testing.assert_array_equal(np.asarray(got), OPS[op](z, valid, footprint, case.radius))


@pytest.mark.parametrize(("case", "footprint"), [(CASES[0], "disk"), (CASES[0], "square"), (CASES[6], "square")],
                         ids=str)
def test_van_herk_matches_scipy_exactly(case, footprint):
    """The van Herk / Gil-Werman path (algorithm="vhgw") gives the same bits as scipy. (Its
    unrolled block scans compile slowly for large disks, so large radii run on squares only.)"""
    z, valid = reference.random_raster(case, seed=1)
    got = jitted_all(case.radius, footprint, algorithm="vhgw")(z, valid)
    for op, result in zip(OPS, got):
        np.testing.assert_array_equal(np.asarray(result), OPS[op](z, valid, footprint, case.radius), err_msg=op)


@pytest.mark.parametrize("footprint", FOOTPRINTS)
@pytest.mark.parametrize("case", CASES[:2], ids=str)
def test_no_mask_matches_scipy(case, footprint):
    z, _ = reference.random_raster(case, seed=2)
    got = jitted_all(case.radius, footprint, ("max_filter", "min_filter"))(z)
    np.testing.assert_array_equal(np.asarray(got[0]), reference.dilation(z, None, footprint, case.radius))
    np.testing.assert_array_equal(np.asarray(got[1]), reference.erosion(z, None, footprint, case.radius))


@pytest.mark.parametrize("footprint", FOOTPRINTS)
@pytest.mark.parametrize("case", CASES[:1], ids=str)
def test_jit_equals_eager(case, footprint):
    z, valid = reference.random_raster(case, seed=3)
    for op in ("opening", "closing"):
        eager = getattr(raster, op)(jnp.asarray(z), jnp.asarray(valid), radius_px=case.radius, footprint=footprint)
        np.testing.assert_array_equal(np.asarray(jitted(op, case.radius, footprint)(z, valid)), np.asarray(eager))


@pytest.mark.parametrize("footprint", FOOTPRINTS)
@pytest.mark.parametrize("case", [CASES[0], CASES[6]], ids=str)
def test_vmap_equals_loop(case, footprint):
    tiles = [reference.random_raster(case, seed=s) for s in range(3)]
    z = np.stack([t[0] for t in tiles])
    valid = np.stack([t[1] for t in tiles])
    for op in ("opening", "closing"):
        fn = jitted(op, case.radius, footprint)
        batched = jax.jit(jax.vmap(fn))(z, valid)
        for b in range(len(tiles)):
            np.testing.assert_array_equal(np.asarray(batched[b]), np.asarray(fn(z[b], valid[b])))


@pytest.mark.parametrize("footprint", FOOTPRINTS)
def test_closing_extensive_idempotent_opening_anti_extensive(footprint):
    case = CASES[0]
    z, valid = reference.random_raster(case, seed=4)
    closed = np.asarray(jitted("closing", case.radius, footprint)(z, valid))
    opened = np.asarray(jitted("opening", case.radius, footprint)(z, valid))
    assert np.all(closed[valid] >= z[valid])
    assert np.all(opened[valid] <= z[valid])
    np.testing.assert_array_equal(np.asarray(jitted("closing", case.radius, footprint)(closed, valid))[valid], closed[valid])
    np.testing.assert_array_equal(np.asarray(jitted("opening", case.radius, footprint)(opened, valid))[valid], opened[valid])


@pytest.mark.parametrize("footprint", FOOTPRINTS)
def test_invalid_padding_never_changes_valid_cells(footprint):
    """A tile padded (south and east) with empty cells, as for a vmap bucket, gives the same
    result on its own cells."""
    case = CASES[0]
    z, valid = reference.random_raster(case, seed=5)
    h, w = case.shape
    zp = np.full((40, 40), 7.0, np.float32)
    vp = np.zeros((40, 40), bool)
    zp[:h, :w], vp[:h, :w] = z, valid
    fn = jitted_all(case.radius, footprint)
    for small, big in zip(fn(z, valid), fn(zp, vp)):
        np.testing.assert_array_equal(np.asarray(big)[:h, :w], np.asarray(small))


@functools.cache
def jitted_traced(max_radius: int):
    """Every op with a traced radius: one compile serves every radius up to `max_radius`."""
    def run(z, valid, radius):
        return [getattr(raster, op)(z, valid, radius_px=radius, footprint="disk", max_radius_px=max_radius)
                for op in OPS]
    return jax.jit(run)


@pytest.mark.parametrize("case", CASES, ids=str)
def test_traced_radius_matches_scipy_exactly(case):
    """A traced radius (`max_radius_px`) gives scipy's bits for every radius up to the bound,
    including 0 and a disk wider than the raster, from one program."""
    z, valid = reference.random_raster(case, seed=6)
    fn = jitted_traced(case.radius + 2)
    for radius in sorted({0, 1, case.radius, case.radius + 2}):
        got = fn(z, valid, jnp.int32(radius))
        for op, result in zip(OPS, got):
            np.testing.assert_array_equal(np.asarray(result), OPS[op](z, valid, "disk", radius),
                                          err_msg=f"{op} r={radius}")


def test_traced_radius_inside_a_loop_equals_static_radii():
    """The use it is made for: incremental openings r = 1..R in one `fori_loop` equal R static
    openings applied one after another, under `vmap` over tiles too."""
    case = Case("loop", (37, 29), radius=6)
    tiles = [reference.random_raster(case, seed=s) for s in range(3)]
    z = np.stack([t[0] for t in tiles])
    valid = np.stack([t[1] for t in tiles])

    def looped(z, valid):
        step = lambda r, s: raster.opening(s, valid, radius_px=r, max_radius_px=case.radius)  # noqa: E731
        return jax.lax.fori_loop(1, case.radius + 1, step, z)

    def unrolled(z, valid):
        for r in range(1, case.radius + 1):
            z = raster.opening(z, valid, radius_px=r)
        return z

    got = jax.jit(jax.vmap(looped))(z, valid)
    for b in range(len(tiles)):
        np.testing.assert_array_equal(np.asarray(got[b]), np.asarray(jax.jit(unrolled)(z[b], valid[b])))


def test_traced_radius_beyond_the_bound_is_clipped():
    z, valid = reference.random_raster(CASES[0], seed=7)
    got = jitted_traced(2)(z, valid, jnp.int32(9))[0]
    np.testing.assert_array_equal(np.asarray(got), reference.erosion(z, valid, "disk", 2))


def test_integer_raster():
    z = np.random.default_rng(0).integers(-50, 50, size=(16, 16)).astype(np.int32)
    got = jax.jit(functools.partial(raster.min_filter, radius_px=3, footprint="disk"))(z)
    expected = ndi.grey_erosion(z, footprint=raster.disk(3), mode="constant", cval=np.iinfo(np.int32).max)
    np.testing.assert_array_equal(np.asarray(got), expected)


def test_bool_raster_grey_ops_with_mask():
    """Grey ops on a bool raster (DMF closes masks inside a tile's valid area): False/True are
    the identities of max/min, so cells outside `valid` never add or remove anything."""
    rng = np.random.default_rng(1)
    m, valid = rng.random((16, 16)) < 0.5, rng.random((16, 16)) < 0.8
    got = jax.jit(functools.partial(raster.closing, radius_px=2, footprint="square"))(m, valid)
    dilated = ndi.maximum_filter(np.where(valid, m, False), size=5, mode="constant", cval=False)
    expected = ndi.minimum_filter(np.where(valid, dilated, True), size=5, mode="constant", cval=True)
    np.testing.assert_array_equal(np.asarray(got), expected)
    assert got.dtype == jnp.bool_


def test_bad_arguments(unchecked):
    z = jnp.zeros((4, 4), jnp.float32)
    with pytest.raises(ValueError, match="radius_px"):
        raster.min_filter(z, radius_px=-1)
    with pytest.raises(ValueError, match="radius_px"):
        raster.min_filter(z, radius_px=1.5)
    with pytest.raises(ValueError, match="footprint"):
        raster.min_filter(z, radius_px=1, footprint="diamond")
    with pytest.raises(ValueError, match="algorithm"):
        raster.min_filter(z, radius_px=1, algorithm="naive")
    with pytest.raises(ValueError, match="valid shape"):
        raster.min_filter(z, jnp.ones((3, 4), bool), radius_px=1)
    with pytest.raises(ValueError, match="disk footprint"):
        raster.min_filter(z, radius_px=jnp.int32(1), footprint="square", max_radius_px=2)
    with pytest.raises(ValueError, match="0..max_radius_px=2"):
        raster.opening(z, radius_px=3, max_radius_px=2)
    with pytest.raises(ValueError, match="^max_radius_px must be an int >= 0, got -1$"):
        raster.min_filter(z, radius_px=jnp.int32(1), max_radius_px=-1)
