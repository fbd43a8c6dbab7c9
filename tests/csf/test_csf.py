"""gfjax.csf against a literal Python transcription of cloth-simulation-filter (reference.py),
against the package itself when installed, and under jit / vmap / point permutations."""
from __future__ import annotations

import functools

import csf_reference as reference
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from gfjax import csf
from gfjax.csf import cloth, stages
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud

CAPACITY = 3000
FAST = csf.Config(iterations=200)


def scene(kind: str, seed: int = 0) -> np.ndarray:
    """Synthetic float64 metres `(n, 3)` on a 24 m x 24 m square, 0.5 m spacing with jitter.

    plane_box: flat ground + a 8 m x 8 m building 6 m high; ramp: a 10 % slope; terrace: a
    0.4 m step across the middle; forest: plane + scattered high points.
    """
    rng = np.random.default_rng(seed)
    g = np.arange(0.0, 24.0, 0.5)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    x = np.clip(x + rng.uniform(-0.1, 0.1, x.shape), 0, 23.9)
    y = np.clip(y + rng.uniform(-0.1, 0.1, y.shape), 0, 23.9)
    z = 100.0 + rng.normal(0, 0.02, x.shape)
    if kind == "plane_box":
        z = z + np.where((abs(x - 12) < 4) & (abs(y - 12) < 4), 6.0, 0.0)
    elif kind == "ramp":
        z = z + 0.1 * x
    elif kind == "terrace":
        z = z + np.where(y > 12, 0.4, 0.0)
    elif kind == "forest":
        trees = rng.random(x.shape) < 0.15
        z = z + np.where(trees, rng.uniform(5, 15, x.shape), 0.0)
    else:
        raise ValueError(kind)
    return np.stack([x, y, z], axis=1)


def truth(kind: str, xyz: np.ndarray) -> np.ndarray:
    """Ground by construction."""
    if kind == "plane_box":
        return ~((abs(xyz[:, 0] - 12) < 4) & (abs(xyz[:, 1] - 12) < 4))
    if kind == "forest":
        return xyz[:, 2] < 100.2
    return np.ones(len(xyz), bool)


def padded(xyz: np.ndarray, capacity: int = CAPACITY) -> tuple[jnp.ndarray, jnp.ndarray]:
    local = (xyz - xyz.min(axis=0)).astype(np.float32)
    buf = np.zeros((capacity, 3), np.float32)
    buf[:len(local)] = local
    valid = np.zeros(capacity, bool)
    valid[:len(local)] = True
    return jnp.asarray(buf), jnp.asarray(valid)


SHAPE = csf.grid_shape(padded(scene("plane_box"))[0], padded(scene("plane_box"))[1], cell_m=1.0)


@pytest.fixture(scope="session")
def classify():
    return jax.jit(lambda xyz, valid, params: csf.filter_points(xyz, valid, params, config=FAST, shape=SHAPE))


# --- the cloth solver against the sequential reference ------------------------------------

SWEEP_CASES = [("random_folded", (9, 13), 3), ("tiny_rigid1", (4, 5), 1), ("unfolded", (3, 20), 2)]


@pytest.mark.parametrize("name,shape,rigidness", SWEEP_CASES, ids=lambda c: str(c))
def test_wavefront_sweep_is_the_package_sweep(name, shape, rigidness):
    rng = np.random.default_rng(len(name))
    u = rng.normal(size=shape).astype(np.float32)
    movable = rng.random(shape) > 0.3
    out = cloth.sweep(jnp.asarray(u), jnp.asarray(movable), jnp.ones(shape, bool), rigidness=rigidness)
    expected = reference.sweep(u.astype(np.float64), movable, rigidness=rigidness)
    np.testing.assert_allclose(np.asarray(out), expected, atol=2e-6)
    assert np.array_equal(np.asarray(out)[~movable], u[~movable])      # fixed particles stay


def surface(kind: str, shape=(12, 14)) -> np.ndarray:
    """Inverted surfaces `[j, i]` for the simulation tests (u = -z)."""
    j, i = np.indices(shape).astype(np.float64)
    z = {"box": np.where((abs(i - 7) < 3) & (abs(j - 6) < 3), 4.0, 0.0),
         "ramp": 0.3 * i, "terrace": np.where(j > 6, 0.8, 0.0)}[kind]
    return (-z).astype(np.float32)


@pytest.mark.parametrize("kind", ["box", "ramp", "terrace"])
def test_simulate_matches_sequential_reference(kind):
    heights = surface(kind)
    start = float(heights.max()) + 0.05
    state = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(start),
                           jnp.float32(0.65), config=csf.Config(iterations=300))
    u, movable, steps = reference.simulate(heights.astype(np.float64), start, iterations=300)
    assert int(state.steps) == steps
    np.testing.assert_array_equal(np.asarray(state.movable), movable)
    np.testing.assert_allclose(np.asarray(state.u), u, atol=1e-4)


def test_a_cloth_resting_everywhere_stops_with_the_cloth_of_the_cap():
    """Once no particle can move, the package runs on to the cap (its stop needs a displacement
    above 0) without changing anything; gfjax stops there, with the same cloth."""
    heights = np.zeros((9, 13), np.float32)
    state = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(0.05),
                           jnp.float32(0.65), config=csf.Config(iterations=300))
    u, movable, steps = reference.simulate(heights.astype(np.float64), 0.05, iterations=300)
    assert steps == 300 and int(state.steps) < 10
    np.testing.assert_array_equal(np.asarray(state.movable), movable)
    np.testing.assert_allclose(np.asarray(state.u), u, atol=1e-6)


def test_a_time_step_too_small_to_move_the_cloth_stops_at_its_fixed_point():
    """dt = 1e-6: gravity's pull (dt^2 scaled twice) is lost to float32 rounding, no particle
    moves, and the package's stop (a displacement above 0) never comes: gfjax stops at the
    second still step, with the cloth the cap would give (the one it started from)."""
    heights = surface("box")
    start = float(heights.max()) + 0.05
    state = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(start),
                           jnp.float32(1e-6), config=csf.Config(iterations=100_000))
    assert int(state.steps) <= 3 and float(state.max_step_m) == 0.0
    np.testing.assert_array_equal(np.asarray(state.u), np.full(heights.shape, start, np.float32))
    capped = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(start),
                            jnp.float32(1e-6), config=csf.Config(iterations=3))
    np.testing.assert_array_equal(np.asarray(state.u), np.asarray(capped.u))


def test_simulate_vmap_runs_each_cloth_to_its_own_stop():
    """A batch shares the loop; a cloth that stops early is frozen at its own stopping step."""
    kinds = ["box", "ramp", "terrace"]
    heights = jnp.asarray(np.stack([surface(k) for k in kinds]))
    start = jnp.max(heights, axis=(1, 2)) + jnp.float32(0.05)
    cfg = csf.Config(iterations=300)
    run = jax.jit(jax.vmap(lambda hh, s0: cloth.simulate(hh, jnp.ones(hh.shape, bool), s0, jnp.float32(0.65),
                                                         config=cfg)))
    batched = run(heights, start)
    singles = [cloth.simulate(heights[k], jnp.ones(heights.shape[1:], bool), start[k], jnp.float32(0.65), config=cfg)
               for k in range(len(kinds))]
    assert len({int(s.steps) for s in singles}) > 1                        # they stop apart
    for k, single in enumerate(singles):
        assert int(batched.steps[k]) == int(single.steps)
        np.testing.assert_array_equal(np.asarray(batched.movable[k]), np.asarray(single.movable))
        np.testing.assert_allclose(np.asarray(batched.u[k]), np.asarray(single.u), atol=1e-6)


def test_simulate_padding_changes_nothing():
    heights = surface("box")
    start = jnp.float32(heights.max() + 0.05)
    cfg = csf.Config(iterations=300)
    small = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), start, jnp.float32(0.65), config=cfg)
    big = np.full((16, 17), -50.0, np.float32)
    big[:12, :14] = heights
    exists = np.zeros((16, 17), bool)
    exists[:12, :14] = True
    state = cloth.simulate(jnp.asarray(big), jnp.asarray(exists), start, jnp.float32(0.65), config=cfg)
    assert int(state.steps) == int(small.steps)
    np.testing.assert_array_equal(np.asarray(state.u)[:12, :14], np.asarray(small.u))


# --- the stages around it --------------------------------------------------------------

def test_particle_heights_and_fill_match_reference():
    rng = np.random.default_rng(3)
    xy = rng.uniform(2.0, 9.0, (60, 2)).astype(np.float32)
    u = rng.normal(size=60).astype(np.float32)
    shape = (12, 12)
    heights, has = jax.jit(stages.particle_heights, static_argnames=("cell_m", "shape"))(
        jnp.asarray(xy), jnp.asarray(u), jnp.ones(60, bool), cell_m=1.0, shape=shape)
    expected = reference.particle_heights(xy, u, shape, 1.0)
    np.testing.assert_array_equal(np.asarray(has), ~np.isnan(expected))
    np.testing.assert_array_equal(np.asarray(heights)[~np.isnan(expected)], expected[~np.isnan(expected)])
    filled = jax.jit(stages.scanline_fill)(heights, has)
    np.testing.assert_array_equal(np.asarray(filled), reference.scanline_fill(expected))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_smooth_slopes_matches_literal_movable_filter(seed):
    rng = np.random.default_rng(seed)
    shape = (14, 16)
    heights = np.round(rng.normal(0, 0.25, shape).cumsum(axis=1), 2).astype(np.float32)
    movable = np.ones(shape, bool)
    movable[rng.random(shape) < 0.15] = False
    if seed == 2:
        movable[:, 8] = False                              # two components of 112 and < 50
        movable[:5, 9:] = False
    u = (heights + rng.uniform(0.1, 2.0, shape)).astype(np.float32)
    u = np.where(movable, u, heights)
    out_u, out_mov = jax.jit(stages.smooth_slopes)(jnp.asarray(u), jnp.asarray(movable),
                                                   jnp.ones(shape, bool), jnp.asarray(heights))
    ref_u, ref_mov = reference.smooth_slopes(u, movable, heights)
    np.testing.assert_array_equal(np.asarray(out_mov), ref_mov)
    np.testing.assert_array_equal(np.asarray(out_u), ref_u.astype(np.float32))


def test_height_above_cloth_is_bilinear():
    rng = np.random.default_rng(4)
    cloth_u = rng.normal(size=(8, 9)).astype(np.float32)
    xy = rng.uniform(2.0, 6.9, (40, 2)).astype(np.float32)
    u = rng.normal(size=40).astype(np.float32)
    out = jax.jit(stages.height_above_cloth, static_argnames="cell_m")(jnp.asarray(xy), jnp.asarray(u), jnp.asarray(cloth_u), cell_m=1.0)
    np.testing.assert_allclose(np.asarray(out), reference.height_above_cloth(xy, u, cloth_u, 1.0), atol=1e-5)


# --- whole filter on synthetic scenes ------------------------------------------------------

@pytest.mark.parametrize("kind", ["plane_box", "ramp", "terrace", "forest"])
def test_scenes(classify, kind):
    xyz = scene(kind)
    buf, valid = padded(xyz)
    ground, diag = classify(buf, valid, csf.Params())
    ground = np.asarray(ground)
    assert not ground[len(xyz):].any()
    ok = np.mean(ground[:len(xyz)] == truth(kind, xyz))
    assert ok > 0.97, (kind, ok)
    assert 0 < int(diag.steps) <= FAST.iterations


def test_jit_matches_eager():
    """Each stage, jitted and op by op (the whole pipeline is jitted in the other tests)."""
    rng = np.random.default_rng(6)
    shape = (4, 5)
    u = jnp.asarray(rng.normal(size=shape), jnp.float32)
    movable = jnp.asarray(rng.random(shape) > 0.3)
    exists = jnp.ones(shape, bool)
    xy = jnp.asarray(rng.uniform(2.0, 3.0, (9, 2)), jnp.float32)
    pu = jnp.asarray(rng.normal(size=9), jnp.float32)
    calls = [
        lambda: stages.smooth_slopes(u, movable, exists, u * 0.5),
        lambda: stages.scanline_fill(*stages.particle_heights(xy, pu, jnp.ones(9, bool), cell_m=1.0, shape=shape)),
        lambda: stages.height_above_cloth(xy, pu, u, cell_m=1.0),
    ]
    for call in calls:
        jitted = jax.jit(call)()
        with jax.disable_jit():
            eager = call()
        for a_, b_ in zip(jax.tree_util.tree_leaves(jitted), jax.tree_util.tree_leaves(eager)):
            np.testing.assert_allclose(np.asarray(a_), np.asarray(b_), atol=1e-6)


def test_vmap_matches_loop(classify):
    scenes = [scene("plane_box", 1), scene("terrace", 2)]
    bufs, valids = zip(*(padded(s) for s in scenes))
    params = csf.Params()
    batched = jax.jit(jax.vmap(lambda a, b: csf.filter_points(a, b, params, config=FAST, shape=SHAPE)))
    ground_b, diag_b = batched(jnp.stack(bufs), jnp.stack(valids))
    for k in range(len(scenes)):
        ground, diag = classify(bufs[k], valids[k], params)
        np.testing.assert_array_equal(np.asarray(ground_b[k]), np.asarray(ground))
        assert int(diag_b.steps[k]) == int(diag.steps)


def test_point_order_does_not_matter(classify):
    xyz = scene("plane_box", 3)
    perm = np.random.default_rng(0).permutation(len(xyz))
    a, _ = classify(*padded(xyz), csf.Params())
    b, _ = classify(*padded(xyz[perm]), csf.Params())
    np.testing.assert_array_equal(np.asarray(a)[:len(xyz)][perm], np.asarray(b)[:len(xyz)])


def test_matches_package_on_scene(monkeypatch):
    monkeypatch.setenv("OMP_NUM_THREADS", "1")        # the package's sequential sweep (no OpenMP races)
    CSF = pytest.importorskip("CSF")
    xyz = scene("plane_box", 5)
    package = CSF.CSF()
    package.params.interations = FAST.iterations
    package.setPointCloud(xyz)
    ground_idx, off = CSF.VecInt(), CSF.VecInt()
    package.do_filtering(ground_idx, off, False)
    expected = np.zeros(len(xyz), bool)
    expected[np.asarray(ground_idx, np.int64)] = True
    ours = csf.filter(Cloud.from_xyz(xyz), config=FAST).ground
    assert np.mean(ours == expected) > 0.995


def test_filter_ignores_noise_and_checks_input():
    xyz = scene("plane_box", 5)                            # the shape and size of the test above
    cls = np.zeros(len(xyz), np.uint8)
    cls[:10] = 7                                          # noise: never ground
    cloud = Cloud.from_xyz(xyz, classification=cls)
    result = csf.filter(cloud, config=FAST)
    truth_ = truth("plane_box", xyz)
    assert not result.ground[:10].any() and np.mean(result.ground[10:] == truth_[10:]) > 0.97
    assert result.diagnostics.cloth_z.shape == result.diagnostics.movable.shape
    with pytest.raises(InputError, match="class_threshold_m"):
        csf.filter(cloud, params=csf.Params(class_threshold_m=-1.0))
    with pytest.raises(InputError, match="returns"):
        csf.filter(cloud, returns="first")
    with pytest.raises(ValueError, match="rigidness"):
        csf.Config(rigidness=0)
    with pytest.raises(ValueError, match="cell_m"):
        csf.Config(cell_m=-1.0)


def test_canonical_grids_and_capacities_bound_the_padding():
    from gfjax.csf.programs import WARM_SIDES, canonical_grid, canonical_points

    sides = sorted({canonical_grid((s, s))[0] for s in range(1, 513)})
    assert sides == list(WARM_SIDES) == [128, 192, 256, 384, 512]     # `warm` compiles every pair
    for h, w in [(1, 1), (65, 300), (511, 513), (1106, 1104), (4000, 70)]:
        ch, cw = canonical_grid((h, w))
        assert h <= ch <= max(128, 1.5 * h, h + 63) and w <= cw <= max(128, 1.5 * w, w + 63)
    assert canonical_points(10) == 1 << 14 and canonical_points(345_966) == 393_216


def test_filter_on_canonical_shapes_labels_as_on_the_cloud_own_grid():
    """`csf.filter` pads the points and the particle grid to canonical shapes: the labels and
    the cloth are those of `filter_points` on the cloud's own arrays and grid."""
    cloud = Cloud.from_xyz(scene("plane_box", seed=3)[:2345] + [5e5, 5e6, 0.0])
    result = csf.filter(cloud, config=FAST)
    local = (cloud.xyz_m - cloud.xyz_m.min(axis=0)).astype(np.float32)
    valid = np.ones(len(local), bool)
    shape = csf.grid_shape(local, valid, cell_m=FAST.cell_m)
    ground, diag = csf.filter_points(local, valid, csf.Params(), config=FAST, shape=shape)
    np.testing.assert_array_equal(result.ground, np.asarray(ground))
    np.testing.assert_array_equal(result.diagnostics.movable, np.asarray(diag.movable)[::-1])
    assert result.diagnostics.cloth_z.shape == shape


@pytest.mark.parametrize("side", [128, 384])
def test_the_memory_estimate_covers_the_compiled_cloth(side):
    # the simulation keeps a snapshot per block in flight, so its memory grows with the side
    # times the area; the estimate the command line checks before a run must follow it
    import dataclasses
    import importlib

    from gfjax.csf.config import ADAPTED, BUFFER_PX, Config, Params

    filter_module = importlib.import_module("gfjax.csf.programs")
    config = dataclasses.replace(Config(), **ADAPTED)
    grid, flag = jax.ShapeDtypeStruct((side, side), np.float32), jax.ShapeDtypeStruct((side, side), np.bool_)
    surface = filter_module.Surface(grid, flag, flag, jax.ShapeDtypeStruct((2,), np.float32),
                                    jax.ShapeDtypeStruct((), np.float32))
    compiled = filter_module.drop_cloth.lower(surface, Params(), config=config).compile()
    needed = compiled.memory_analysis().temp_size_in_bytes
    # `filter` runs it as three programs (`start_cloth`, `advance_cloth`, `finish_cloth`) that
    # hand the simulation's state on: each holds its arguments, results (less those written
    # into donated arguments) and temporaries
    filled, run = jax.eval_shape(functools.partial(filter_module.start_cloth, config=config), surface, Params())
    for lowered in (filter_module.start_cloth.lower(surface, Params(), config=config),
                    filter_module.advance_cloth.lower(run, jax.ShapeDtypeStruct((), np.int32), config=config),
                    filter_module.finish_cloth.lower(run, filled, flag, config=config)):
        memory = lowered.compile().memory_analysis()
        needed = max(needed, memory.argument_size_in_bytes + memory.output_size_in_bytes - memory.alias_size_in_bytes
                     + memory.temp_size_in_bytes)
    extent = (side - 2 * BUFFER_PX - 1) * config.cell_m
    estimate, = config.memory_estimates((extent, extent))
    assert needed <= estimate.n_bytes <= 1.5 * needed
