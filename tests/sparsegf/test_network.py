"""SparseGF's network, model files, packing, filter and training step on a small synthetic scene.

Every pack here has the smallest capacity, so the network compiles once for prediction and
once for the training step (a few seconds each with the micro network)."""
from __future__ import annotations

import sys

import equinox as eqx
import jax
import numpy as np
import pytest

import gfjax
from gfjax import sparsegf
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.sparsegf import checkpoint, pipeline, programs, train
from gfjax.sparsegf.config import SMRF_OBJECT_PROBABILITY, Config, model_settings
from gfjax.sparsegf.features import n_features
from gfjax.sparsegf.filter import patches
from gfjax.sparsegf.model import NET_PRESETS, NetConfig, count_parameters, init

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

# The network and pipeline tests use the feature set without SMRF's surface: no SMRF to compile.
FEATURES = "xyz+tophat"
MICRO = NetConfig(stem=4, planes=(4,) * 8, layers=(1,) * 8, refine=4, point=4, in_features=n_features(FEATURES))


def scene(seed=0):
    """A 60 x 40 m sloping ground at 1 pt/m^2 with a 10 x 10 x 6 m box on it (class 2 / 6)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, [60, 40], (2400, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.03, len(xy))
    roof = (np.abs(xy[:, 0] - 30) < 5) & (np.abs(xy[:, 1] - 20) < 5)
    z = np.where(roof, z + 6.0, z)
    cls = np.where(roof, 6, 2).astype(np.uint8)
    return np.column_stack([xy + [5e5, 5e6], z]), cls


@pytest.fixture(scope="module")
def net():
    return init(MICRO, key=jax.random.key(2))


def small_pack(found, plans=None):
    """`found` in a pack of the shape `sparsegf.filter` gives the scene's patches (a small
    pack), so that these tests run the network program the filter's tests compile."""
    return pipeline.pack(found, pipeline.PACK_SLOTS, plans, min_capacity=pipeline.SMALL_PACK_VOXELS)


def test_parameter_counts():
    paper = count_parameters(NET_PRESETS["paper"])
    assert abs(paper - 37.9e6) <= 0.01 * 37.9e6                     # MinkUNet34C + refinement
    tiny = count_parameters(NET_PRESETS["tiny"])
    assert tiny * 4 <= 5 * 2 ** 20


def test_a_network_made_for_its_shapes_has_the_shapes_of_a_drawn_one():
    drawn, shapes = init(MICRO, key=jax.random.key(0)), init(MICRO, key=None)
    assert jax.tree.structure(drawn) == jax.tree.structure(shapes)
    for a, b in zip(jax.tree.leaves(drawn), jax.tree.leaves(shapes)):
        assert (np.shape(a), getattr(a, "dtype", type(a))) == (np.shape(b), getattr(b, "dtype", type(b)))
    assert not any(np.any(np.asarray(w)) for w in jax.tree.leaves(eqx.filter(shapes.net, eqx.is_inexact_array))
                   if np.ndim(w) > 1)                                       # no weight drawn


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    net = init(MICRO, key=jax.random.key(1))
    path = tmp_path / "m.eqx"
    checkpoint.save(path, net, {"seed": 3})
    back, header = checkpoint.load(path)
    assert header["meta"] == {"seed": 3} and back.net.config == MICRO
    for a, b in zip(jax.tree_util.tree_leaves(net), jax.tree_util.tree_leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    data = path.read_bytes()
    (tmp_path / "short.eqx").write_bytes(data[: len(data) - 100])
    (tmp_path / "long.eqx").write_bytes(data + b"x")
    (tmp_path / "foreign.eqx").write_bytes(b"PK\x03\x04 not a model")
    (tmp_path / "format.eqx").write_bytes(data.replace(f'"format": {checkpoint.FORMAT}'.encode(), b'"format": 9', 1))
    cases = {"missing.eqx": "model file not found", "short.eqx": "truncated", "long.eqx": "trailing bytes",
             "foreign.eqx": "not a gfjax SparseGF model", "format.eqx": "model format 9"}
    for name, message in cases.items():
        with pytest.raises(InputError, match=message) as err:
            checkpoint.load(tmp_path / name)
        assert name in str(err.value)


def test_a_model_whose_inputs_differ_from_its_settings_is_refused(tmp_path):
    net = init(MICRO, key=jax.random.key(1))                       # 12 input features
    path = tmp_path / "m.eqx"
    checkpoint.save(path, net, {"config": {"features": "xyz"}})     # 4
    with pytest.raises(InputError, match="m.eqx: the network takes 12 input features, its settings give 4"):
        sparsegf.load_model(path)


def test_a_model_files_settings_apply_but_never_its_decision(tmp_path):
    net = init(MICRO, key=jax.random.key(1))                       # 12 input features: xyz+tophat
    path = tmp_path / "m.eqx"
    checkpoint.save(path, net, {"config": {"features": "xyz+tophat", "max_context_points": 5000,
                                           "decision": "network", "smrf_object_probability": 0.42}})
    _, config = sparsegf.load_model(path)
    assert config.max_context_points == 5000 and config.features == "xyz+tophat"
    assert (config.decision, config.smrf_object_probability) == (Config.decision, SMRF_OBJECT_PROBABILITY)
    recorded = model_settings(Config(smrf_object_probability=0.42))          # what `gfjax train` writes
    assert "smrf_object_probability" not in recorded and recorded["features"] == Config.features


def test_a_model_object_given_settings_of_other_inputs_is_refused(net):
    xyz, cls = scene()
    with pytest.raises(InputError, match="the model takes 12 input features, the settings' feature set "
                                         "'xyz\\+tophat\\+smrf' gives 14"):
        sparsegf.filter(Cloud.from_xyz(xyz, classification=cls), model=net)             # Config(): 14


def test_a_patch_gets_the_same_output_alone_or_packed_with_others(net):
    xyz, _ = scene()
    found = list(patches(xyz, Config(features=FEATURES)))
    assert len(found) == 2
    alone = []
    for p in found:
        single = small_pack([p])
        alone += pipeline.unpack(single, np.asarray(programs.predict(net, single)[0]))
    packed = small_pack(found)
    together = np.asarray(programs.predict(net, packed)[0])
    single = small_pack(found[:1])
    assert packed.coords.shape == single.coords.shape and packed.point_row.shape == single.point_row.shape
    for values, own in zip(pipeline.unpack(packed, together), alone):
        np.testing.assert_allclose(values, own, rtol=1e-4, atol=1e-6)


def test_points_of_one_voxel_can_get_different_outputs(net):
    xyz, _ = scene()
    patch = next(patches(xyz, Config(features=FEATURES)))
    packed = small_pack([patch])
    prob = pipeline.unpack(packed, np.asarray(programs.predict(net, packed)[0]))[0]
    shared = np.flatnonzero(patch.central_counts() >= 2)
    assert len(shared)
    spread = [np.ptp(prob[patch.point_voxel == v]) for v in shared]
    assert max(spread) > 0


def test_filter_votes_every_point(net):
    xyz, cls = scene()
    cloud = Cloud.from_xyz(xyz, classification=cls)
    result = sparsegf.filter(cloud, model=net, config=Config(features=FEATURES, decision="network"))
    assert result.ground.shape == (len(xyz),)
    d = result.diagnostics
    assert np.all(d.votes >= 1) and d.n_patches == 2 and d.smrf_ground is None    # SMRF not run
    assert np.all((d.prob_ground >= 0) & (d.prob_ground <= 1))
    np.testing.assert_array_equal(result.ground, d.prob_ground > 0.5)


def test_a_tiny_cloud_runs_in_a_tiny_pack_with_the_votes_of_a_small_one(net, monkeypatch):
    import importlib

    xyz, cls = scene()
    xyz = xyz[(xyz[:, 0] < 5e5 + 20) & (xyz[:, 1] < 5e6 + 20)]            # 400 points, one patch
    config = Config(features=FEATURES, decision="network")
    module = importlib.import_module("gfjax.sparsegf.filter")
    capacities = []

    def pack(*args, min_capacity, **kw):
        capacities.append(min_capacity)
        return pipeline.pack(*args, min_capacity=min_capacity, **kw)

    monkeypatch.setattr(module, "pack", pack)
    tiny = sparsegf.filter(Cloud.from_xyz(xyz), model=net, config=config).diagnostics
    monkeypatch.setattr(module, "min_capacity", lambda *a, **kw: pipeline.SMALL_PACK_VOXELS)
    small = sparsegf.filter(Cloud.from_xyz(xyz), model=net, config=config).diagnostics
    assert capacities == [pipeline.TINY_PACK_VOXELS, pipeline.SMALL_PACK_VOXELS] and tiny.n_patches == 1
    np.testing.assert_array_equal(tiny.votes, small.votes)
    np.testing.assert_allclose(tiny.prob_ground, small.prob_ground, rtol=1e-5, atol=1e-6)


def test_a_tiny_cloud_loads_its_network_program_once_and_first(net, tmp_path, monkeypatch):
    from gfjax import aot, cache
    from gfjax.aot import calls

    monkeypatch.setitem(cache._state, "set_up", True)      # the store on, in a folder of this test
    aot.enable(tmp_path / "export")
    built = []
    load_or_compile = calls._load_or_compile

    def spy(fn, *args):
        built.append(getattr(fn, "__name__", fn))
        return load_or_compile(fn, *args)

    monkeypatch.setattr(calls, "_load_or_compile", spy)
    xyz, _ = scene()
    xyz = xyz[(xyz[:, 0] < 5e5 + 20) & (xyz[:, 1] < 5e6 + 20)]            # 400 points, one patch
    config = Config(features=FEATURES, decision="network")
    assert pipeline.fits_tiny_pack(xyz, config) and not pipeline.fits_tiny_pack(scene()[0], config)
    try:
        first = sparsegf.filter(Cloud.from_xyz(xyz), model=net, config=config)
        again = sparsegf.filter(Cloud.from_xyz(xyz), model=net, config=config)
    finally:
        aot.disable()
    # the network's program is loaded before any other, once, and the pack runs it
    assert built == ["predict_points", "_point_inputs", "_soft_vote"]
    np.testing.assert_array_equal(first.diagnostics.prob_ground, again.diagnostics.prob_ground)


@pytest.mark.parametrize("in_flight", [1, 2, 3])
def test_packs_run_side_by_side_give_the_votes_of_one_pack(net, in_flight, monkeypatch):
    filter_module = sys.modules["gfjax.sparsegf.filter"]
    xyz, _ = scene()
    config = Config(features=FEATURES, decision="network")
    together = filter_module.ground_probability(net, xyz, config)
    monkeypatch.setattr(filter_module, "IN_FLIGHT", in_flight)
    monkeypatch.setattr(filter_module, "group", lambda todo, slots: ([p] for p in todo))   # a pack per patch
    apart = filter_module.ground_probability(net, xyz, config)
    assert together[2] == apart[2] == 2
    np.testing.assert_array_equal(together[1], apart[1])
    np.testing.assert_allclose(together[0], apart[0], atol=1e-6)


def test_the_default_decision_arbitrates_smrfs_verdict(net):
    xyz, cls = scene()
    cloud = Cloud.from_xyz(xyz, classification=cls)
    config = Config(features=FEATURES)
    assert config.decision == "network+smrf"
    result = sparsegf.filter(cloud, model=net, config=config)
    d = result.diagnostics
    np.testing.assert_array_equal(d.smrf_ground, gfjax.smrf.filter(cloud).ground)
    np.testing.assert_array_equal(result.ground, np.asarray(sparsegf.decide(d.prob_ground, d.smrf_ground, config=config)))
    alone = sparsegf.filter(cloud, model=net, config=Config(features=FEATURES, decision="network"))
    np.testing.assert_array_equal(alone.diagnostics.prob_ground, d.prob_ground)     # the network is unchanged


def test_a_core_labels_as_the_whole_cloud_with_fewer_patches(net, monkeypatch):
    # a quarter of the scene's points four times side by side (240 x 40 m, 5 patches), a pack
    # per patch (the small packs' program): with the first scene as the core, its points and
    # those within the reach have the whole cloud's votes and labels from fewer patches; the
    # far points, no patch ran for, take SMRF's verdict
    from gfjax.sparsegf.config import CORE_REACH_M

    monkeypatch.setattr(sys.modules["gfjax.sparsegf.filter"], "group", lambda todo, slots: ([p] for p in todo))
    parts = [scene(seed) for seed in range(4)]
    xyz = np.concatenate([p[0][::4] + [60.0 * i, 0.0, 0.0] for i, p in enumerate(parts)])
    cloud = Cloud.from_xyz(xyz, classification=np.concatenate([p[1][::4] for p in parts]))
    config = Config(features=FEATURES)
    whole = sparsegf.filter(cloud, model=net, config=config)
    x = xyz[:, 0] - xyz[:, 0].min()
    core = x < 60.0
    cored = sparsegf.filter(cloud, model=net, config=config, core=core)
    assert cored.diagnostics.n_patches < whole.diagnostics.n_patches
    near = x < 60.0 + CORE_REACH_M
    np.testing.assert_array_equal(cored.diagnostics.votes[near], whole.diagnostics.votes[near])
    np.testing.assert_allclose(cored.diagnostics.prob_ground[near], whole.diagnostics.prob_ground[near], atol=1e-6)
    np.testing.assert_array_equal(cored.ground[core], whole.ground[core])
    far = cored.diagnostics.votes == 0
    assert far.any() and not far[near].any()
    assert (cored.ground[far] == cored.diagnostics.smrf_ground[far]).mean() > 0.95
    # a core of the wrong shape is refused before any work: SMRF's prior does not run
    monkeypatch.setattr(sys.modules["gfjax.sparsegf.filter"], "smrf_heights", lambda *a: pytest.fail("the prior ran"))
    with pytest.raises(InputError, match="core must have shape"):
        sparsegf.filter(cloud, model=net, config=config, core=core[1:])


def test_training_steps_lower_the_loss_and_keep_the_calibrated_statistics(net):
    """(That a run repeats to the bit: `test_a_short_training_run_twice_gives_the_same_weights_to_the_bit`.)"""
    xyz, cls = scene()
    data = [train.labelled(xyz, cls)]
    steps = list(train.training_batches(data, Config(features=FEATURES), batch_size=4, rng=np.random.default_rng(0)))
    assert len(steps[0].packed.patches) >= 2         # the shifted grid has more, smaller patches
    step = steps[0]
    assert step.labels.shape == step.bins.shape == step.packed.point_valid.shape
    assert step.packed.point_valid.sum() == step.packed.weight.sum() and step.labels.any()
    model = train.calibrate(net, steps)
    measured = jax.tree.leaves(model.state)
    assert any(not np.array_equal(a, b) for a, b in zip(measured, jax.tree.leaves(net.state)))
    opt, state = train.init(model)
    losses = []
    for _ in range(6):
        model, state, loss, overflowed = train.train_step(model, state, step, opt, lr=1e-2)
        assert not overflowed
        losses.append(float(loss.total))
    for a, b in zip(measured, jax.tree.leaves(model.state)):       # statistics stay frozen
        np.testing.assert_array_equal(a, b)
    assert np.all(np.isfinite(losses)) and losses[-1] < losses[0]
    assert train.optimizer() is train.optimizer()     # one static optimizer: the step compiles once


def short_training(net):
    """`train.fit` end to end on the scene and a thinned copy of it (patches topped up and capped,
    batch norms calibrated each epoch, two epochs): every array of the trained network and its
    statistics, and the epochs' losses."""
    xyz, cls = scene()
    cloud, config = Cloud.from_xyz(xyz, classification=cls), Config(features=FEATURES)
    data = [train.labelled_cloud(cloud, config)]
    data += train.thinned([cloud], config, copies=1, seed=0, low_pts_m2=0.2)
    model, logs = train.fit(net, data, config=config, epochs=2, batch_size=4, seed=0,
                            min_patches=3, max_patches=3, lam=0.0)
    arrays = [np.asarray(a) for a in jax.tree.leaves(eqx.filter((model.net, model.state), eqx.is_array))]
    return arrays, [(log.loss, log.loss_hag) for log in logs]


def test_a_short_training_run_twice_gives_the_same_weights_to_the_bit(net):
    """A recipe run again on one machine is the same model: no draw outside the seed, no order
    that follows timing. (Another machine may round otherwise: XLA's CPU programs depend on the
    cores they get, `experiments/results/sparsegf_model.md`.)"""
    first, losses = short_training(net)
    again, losses_again = short_training(net)
    assert losses == losses_again and np.all(np.isfinite(losses))
    assert len(first) == len(again)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)


def test_a_model_file_records_the_machine_its_bits_depend_on():
    import json

    facts = train.machine()
    assert json.loads(json.dumps(facts)) == facts                  # goes into the file's JSON header
    assert facts["cpus"] >= 1 and facts["processor"] and facts["jax"] == jax.__version__
    assert len(facts["cpu_flags_sha256"]) == 16 and isinstance(facts["numpy_simd"], list)


def test_a_small_file_is_drawn_again_until_it_gives_min_patches():
    xyz, cls = scene()
    big = np.column_stack([xyz[:, 0] * 4 - 3 * xyz[0, 0], xyz[:, 1] * 4 - 3 * xyz[0, 1], xyz[:, 2]])
    data = [train.labelled(xyz, cls), train.labelled(big, cls)]     # about 2 and 20 patches a pass

    def count(min_patches):
        steps = train.training_batches(data, Config(features=FEATURES), batch_size=4, rng=np.random.default_rng(3),
                                       min_patches=min_patches)
        return sum(len(step.packed.patches) for step in steps)

    one_pass = count(0)
    assert 10 < one_pass < 40
    assert count(1) == one_pass                       # a minimum every file meets changes nothing
    assert count(40) == 80                            # both files topped up to exactly 40
    assert train.count_patches(data, Config(features=FEATURES), 40) == 80
    assert count_capped(data[1:], 5) == 5             # the large file cut down to exactly 5
    assert count_capped(data, 1) == 2                 # both files cut down to one
    assert train.count_patches(data, Config(features=FEATURES), 0, 1) == 2


def count_capped(data, max_patches):
    steps = train.training_batches(data, Config(features=FEATURES), batch_size=4, rng=np.random.default_rng(3),
                                   max_patches=max_patches)
    return sum(len(step.packed.patches) for step in steps)


def test_thinned_copies_are_sparser_subsets_with_their_labels_and_repeat_with_the_seed():
    from gfjax import adaptive

    xyz, cls = scene()
    cloud, config = Cloud.from_xyz(xyz, classification=cls), Config(features=FEATURES)
    whole = train.labelled_cloud(cloud, config)
    density = 1.0 / adaptive.measure(cloud.xyz_m).spacing_m ** 2
    copies = train.thinned([cloud], config, copies=3, seed=0, low_pts_m2=density / 20)
    assert len(copies) == 3
    rows = {tuple(p): i for i, p in enumerate(map(tuple, whole.xyz_m))}
    for c in copies:
        assert 0 < len(c.xyz_m) < len(xyz)
        index = np.asarray([rows[tuple(p)] for p in c.xyz_m])       # a subset of the cloud's points
        np.testing.assert_array_equal(c.ground, whole.ground[index])
    again = train.thinned([cloud], config, copies=3, seed=0, low_pts_m2=density / 20)
    assert all(np.array_equal(a.xyz_m, b.xyz_m) for a, b in zip(copies, again))
    assert train.thinned([cloud], config, copies=3, seed=0, low_pts_m2=density) == []   # no sparser density to draw


def test_training_takes_the_points_of_a_cloud_the_filter_feeds_its_network(net):
    """A low outlier labelled ground (as in some ISPRS samples) and a noise point: training
    leaves both out of its inputs and its scores, as the filter leaves them out of SMRF's prior,
    the features and the patches; so do its thinned copies and its validation."""
    xyz, cls = scene()
    xyz = np.vstack([xyz, xyz[100] - [0.0, 0.0, 30.0], xyz[200] + [0.0, 0.0, 40.0]])
    cls = np.append(cls, [2, 7]).astype(np.uint8)
    cloud, config = Cloud.from_xyz(xyz, classification=cls), Config(features=FEATURES)
    data = train.labelled_cloud(cloud, config)
    seen = sparsegf.filter(cloud, model=net, config=config).diagnostics.votes > 0
    assert not seen[-2:].any() and seen[:-2].all()
    np.testing.assert_array_equal(data.xyz_m, cloud.xyz_m[seen])
    np.testing.assert_array_equal(data.ground, cls[seen] == 2)
    for copy in train.thinned([cloud], config, copies=4, seed=0, low_pts_m2=0.2):
        assert copy.xyz_m[:, 2].min() > xyz[:-2, 2].min() - 1.0 and copy.xyz_m[:, 2].max() < xyz[:-2, 2].max() + 1.0


def test_a_pack_that_overflows_the_standard_plan_runs_again_with_a_grown_plan(net):
    # a solid 24 x 24 x 12 block of voxels (a small pack's 8,192 rows hold its 6,912): 27
    # kernel-3 neighbours each, more than the standard plan's room, so the first run overflows
    xyz = np.stack(np.meshgrid(np.arange(24), np.arange(24), np.arange(12), indexing="ij"), -1).reshape(-1, 3)
    xyz = xyz * 0.5 + 0.25 + np.asarray([5e5, 5e6, 100.0])
    patch = next(patches(xyz, Config(features=FEATURES)))
    plans = {}
    packed = small_pack([patch], plans)
    assert len(packed.coords) == pipeline.SMALL_PACK_VOXELS and len(patch.coords) == 24 * 24 * 12
    calls = []

    def run(packed):
        prob, overflowed = programs.predict(net, packed)
        calls.append(bool(overflowed))
        return prob, overflowed

    prob = pipeline.run_with_room(run, packed, plans)
    assert calls == [True, False]
    grown = plans[len(packed.coords)]
    assert grown == pipeline.grow_plan(packed).plan and grown != packed.plan
    again = pipeline.run_with_room(run, small_pack([patch], plans), plans)
    assert calls[2:] == [False]
    np.testing.assert_array_equal(np.asarray(prob), np.asarray(again))
    values = pipeline.unpack(packed, np.asarray(prob))[0]
    assert len(values) and np.all(np.isfinite(values))


def test_the_shipped_model_says_the_densities_it_saw():
    from gfjax.sparsegf.filter import trained_density

    low, high = trained_density()
    assert 0.05 < low < 0.1 and 20 < high < 30          # thinned copies down to 0.1, St Barth at 24.5


def test_a_model_without_densities_has_no_range(tmp_path):
    from gfjax.sparsegf.filter import trained_density

    path = tmp_path / "m.eqx"
    checkpoint.save(path, init(MICRO, key=jax.random.key(1)), {"inputs": {"density_pts_m2": "junk"}})
    assert trained_density(path) is None
    checkpoint.save(path, init(MICRO, key=jax.random.key(1)), {})
    assert trained_density(path) is None
