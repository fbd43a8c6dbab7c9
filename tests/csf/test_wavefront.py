"""gfjax.csf.wavefront: the folded slot layout reaches the true neighbours, and `relax_block`
is the package's per-particle spring walk (numpy, one particle at a time), under jit and vmap."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax.csf import wavefront as wf

LAYOUT_SHAPES = [(1, 1), (4, 5), (9, 13), (3, 20), (30, 7), (17, 64)]


@pytest.mark.parametrize("shape", LAYOUT_SHAPES, ids=str)
def test_layout_reaches_true_neighbours(shape):
    h, w = shape
    lay = wf.layout(shape)
    slots = lay.to_slots.reshape(lay.rows, lay.lanes)
    empty = h * w
    assert np.array_equal(np.sort(slots[slots != empty]), np.arange(h * w))    # one slot each
    for j in range(h):
        for i in range(w):
            row, lane = divmod(int(lay.from_slots[j * w + i]), lay.lanes)
            assert slots[row, lane] == j * w + i
            for di, dj in wf.SPRINGS:
                reached = slots[row + di + wf.SKEW * dj, (lane + dj) % lay.lanes]
                inside = 0 <= i + di < w and 0 <= j + dj < h
                assert reached == ((j + dj) * w + i + di if inside else empty), (j, i, di, dj)
    last = lay.last_group * wf.PERIOD + lay.last_phase
    assert (slots[last] != empty).any() and (slots[last + 1:] == empty).all()


@pytest.mark.parametrize("lanes", [1, 3, 4, 9])
def test_halo_wraps_lanes(lanes):
    a = np.arange(2 * lanes).reshape(2, lanes)
    expected = np.take(a, np.arange(-wf.HALO, lanes + wf.HALO), axis=-1, mode="wrap")
    np.testing.assert_array_equal(np.asarray(wf.add_halo(jnp.asarray(a))), expected)
    stale = expected.copy()
    stale[:, :wf.HALO] = -1
    stale[:, -wf.HALO:] = -2
    np.testing.assert_array_equal(np.asarray(jax.jit(wf.refresh_halo)(jnp.asarray(stale))), expected)


GROUPS, LANES = 3, 6


def random_slots(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Heights and kinds of `(GROUPS + 1) * PERIOD` slot rows of `LANES` lanes (no halo)."""
    rng = np.random.default_rng(seed)
    shape = ((GROUPS + 1) * wf.PERIOD, LANES)
    u = rng.normal(size=shape).astype(np.float32)
    kind = rng.choice([wf.EMPTY, wf.FIXED, wf.MOVABLE], p=[0.1, 0.3, 0.6], size=shape).astype(np.int8)
    return u, kind


def reference_relax(u: np.ndarray, kind: np.ndarray, live: np.ndarray, phase: int, both: float,
                    single: float) -> np.ndarray:
    """Each live block's centre particles (slot row `PERIOD g + phase + REACH`) one after
    another (lanes in any order: they touch disjoint particles), each walking its springs as
    Particle.cpp `satisfyConstraintSelf`, in float64."""
    out = u.astype(np.float64)
    for g in np.flatnonzero(live):
        centre = wf.PERIOD * g + phase + wf.REACH
        for lane in range(LANES):
            c = (centre, lane)
            for di, dj in wf.SPRINGS:
                q = (centre + di + wf.SKEW * dj, (lane + dj) % LANES)
                if kind[c] == wf.EMPTY or kind[q] == wf.EMPTY:
                    continue
                mov_p, mov_q = kind[c] == wf.MOVABLE, kind[q] == wf.MOVABLE
                gap = out[q] - out[c]
                if mov_p:
                    out[c] += gap * (both if mov_q else single)
                if mov_q:
                    out[q] -= gap * (both if mov_p else single)
    return out


def relax_unhaloed(u, kind, live, phase):
    out = wf.relax_block(wf.add_halo(u), wf.add_halo(kind), live, phase, double_move=0.468, single_move=0.657)
    return out[:, wf.HALO:-wf.HALO]


@pytest.fixture(scope="module")
def relax():
    return jax.jit(relax_unhaloed)


@pytest.mark.parametrize("seed,phase", [(0, 0), (1, 13), (2, wf.PERIOD - 1)])
def test_relax_block_is_the_sequential_walk(relax, seed, phase):
    u, kind = random_slots(seed)
    live = np.array([True, seed != 1, True])
    expected = reference_relax(u, kind, live, phase, 0.468, 0.657)
    out = np.asarray(relax(jnp.asarray(u), jnp.asarray(kind), jnp.asarray(live), jnp.int32(phase)))
    np.testing.assert_allclose(out, expected, atol=2e-6)
    if not live.all():
        untouched = np.ones(len(u), bool)
        untouched[wf.PERIOD * 1 + phase: wf.PERIOD * 2 + phase] = False
        np.testing.assert_array_equal(out[~untouched], u[~untouched])


def test_relax_block_eager_and_vmap(relax):
    slots = [random_slots(seed) for seed in (3, 4)]
    u, kind = (jnp.asarray(np.stack(a)) for a in zip(*slots))
    live = jnp.ones((len(slots), GROUPS), bool)
    phase = jnp.asarray([5, 17], jnp.int32)
    batched = jax.jit(jax.vmap(relax))(u, kind, live, phase)
    with jax.disable_jit():
        eager = relax_unhaloed(u[0], kind[0], live[0], phase[0])
    np.testing.assert_allclose(np.asarray(eager), np.asarray(relax(u[0], kind[0], live[0], phase[0])), atol=1e-6)
    for k in range(len(slots)):
        np.testing.assert_array_equal(np.asarray(batched[k]), np.asarray(relax(u[k], kind[k], live[k], phase[k])))
