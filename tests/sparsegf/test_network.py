"""SparseGF's network, model files, filter and training step on a small synthetic scene."""
from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import pytest

from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.sparsegf import checkpoint
from gfjax import sparsegf
from gfjax.sparsegf import train
from gfjax.sparsegf.config import Config
from gfjax.sparsegf.model import NET_PRESETS, NetConfig, SparseGFNet, count_parameters

MICRO = NetConfig(stem=4, planes=(4,) * 8, layers=(1,) * 8, refine=4, groups=2)


def scene(seed=0):
    """A 60 x 40 m sloping ground at 1 pt/m^2 with a 10 x 10 x 6 m box on it (class 2 / 6)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, [60, 40], (2400, 2))
    z = 100 + 0.05 * xy[:, 0] + rng.normal(0, 0.03, len(xy))
    roof = (np.abs(xy[:, 0] - 30) < 5) & (np.abs(xy[:, 1] - 20) < 5)
    z = np.where(roof, z + 6.0, z)
    cls = np.where(roof, 6, 2).astype(np.uint8)
    return np.column_stack([xy + [5e5, 5e6], z]), cls


def test_parameter_counts():
    paper = count_parameters(NET_PRESETS["paper"])
    assert abs(paper - 37.9e6) <= 0.01 * 37.9e6                     # MinkUNet34C + refinement
    tiny = count_parameters(NET_PRESETS["tiny"])
    assert tiny * 4 <= 5 * 2 ** 20


def test_checkpoint_round_trip_and_bad_files(tmp_path):
    net = SparseGFNet(MICRO, key=jax.random.key(1))
    path = tmp_path / "m.eqx"
    checkpoint.save(path, net, {"seed": 3})
    back, header = checkpoint.load(path)
    assert header["meta"] == {"seed": 3} and back.config == MICRO
    for a, b in zip(jax.tree_util.tree_leaves(net), jax.tree_util.tree_leaves(back)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    data = path.read_bytes()
    (tmp_path / "short.eqx").write_bytes(data[: len(data) - 100])
    (tmp_path / "long.eqx").write_bytes(data + b"x")
    (tmp_path / "foreign.eqx").write_bytes(b"PK\x03\x04 not a model")
    (tmp_path / "format.eqx").write_bytes(data.replace(b'"format": 1', b'"format": 9', 1))
    cases = {"missing.eqx": "model file not found", "short.eqx": "truncated", "long.eqx": "trailing bytes",
             "foreign.eqx": "not a gfjax SparseGF model", "format.eqx": "model format 9"}
    for name, message in cases.items():
        with pytest.raises(InputError, match=message) as err:
            checkpoint.load(tmp_path / name)
        assert name in str(err.value)


def test_filter_votes_every_point_and_a_training_step_lowers_the_loss():
    xyz, cls = scene()
    cloud = Cloud.from_xyz(xyz, classification=cls)
    net = SparseGFNet(MICRO, key=jax.random.key(2))
    result = sparsegf.filter(cloud, model=net)
    assert result.ground.shape == (len(xyz),)
    assert np.all(result.diagnostics.votes >= 1)
    p = result.diagnostics.prob_ground
    assert np.all((p >= 0) & (p <= 1))

    data = [train.labelled(xyz, cls)]
    batch, labels, bins = next(train.training_batches(data, Config(), batch_size=2, rng=np.random.default_rng(0)))
    opt, state = train.init(net, 20)
    losses = []
    for _ in range(6):
        net, state, loss, overflowed = train.train_step(net, state, batch, labels, bins, opt)
        assert not overflowed
        losses.append(float(loss.total))
    assert np.all(np.isfinite(losses)) and losses[-1] < losses[0]


def test_a_patch_that_overflows_the_standard_plan_runs_again_with_a_grown_plan():
    from gfjax.sparsegf import pipeline

    from gfjax.sparsegf.filter import patches

    # a solid 30 x 30 x 18 block of voxels filling its capacity bucket: 27 kernel-3 neighbours
    # each, more than the standard plan's room, so the first run overflows
    xyz = np.stack(np.meshgrid(np.arange(30), np.arange(30), np.arange(18), indexing="ij"), -1).reshape(-1, 3)
    xyz = xyz * 0.5 + 0.25 + np.asarray([5e5, 5e6, 100.0])
    net = SparseGFNet(MICRO, key=jax.random.key(3))
    patch = next(patches(xyz, Config()))
    plans = {}
    batch = pipeline.stack([patch], plans)
    b = batch.patch
    calls = []

    def run(batch):
        prob, overflowed = pipeline.predict_batch(net, b.coords, b.feats, b.vvalid, b.point_voxel, b.central,
                                                  batch.plan)
        calls.append(bool(overflowed))
        return prob, overflowed

    prob = pipeline.run_with_room(run, batch, plans)
    assert calls == [True, False]
    grown = plans[len(patch.coords)]
    assert grown == pipeline.grow_plan(batch).plan and grown != batch.plan
    again = pipeline.run_with_room(run, pipeline.stack([patch], plans), plans)
    assert calls[2:] == [False]
    np.testing.assert_array_equal(np.asarray(prob), np.asarray(again))
    central = b.central[0] & (b.point_voxel[0] >= 0)
    assert central.any() and np.all(np.isfinite(np.asarray(prob)[0][central]))


def test_rows_that_fill_a_short_batch_change_neither_loss_nor_gradient():
    xyz, cls = scene()
    one_patch = xyz[:, 0] < 5e5 + 40.0                          # one 50 m partition cell
    data = [train.labelled(xyz[one_patch], cls[one_patch])]
    net = SparseGFNet(MICRO, key=jax.random.key(4))
    losses, grads = [], []
    for batch_size in (1, 2):
        batch, labels, bins = next(train.training_batches(data, Config(), batch_size=batch_size,
                                                          rng=np.random.default_rng(0)))
        assert batch.patch.index.shape[0] == batch_size
        opt, state = train.init(net, 10)
        new, _, loss, overflowed = train.train_step(net, state, batch, labels, bins, opt)
        assert not overflowed
        losses.append(float(loss.total))
        grads.append([np.asarray(a) for a in jax.tree_util.tree_leaves(eqx.filter(new, eqx.is_array))])
    np.testing.assert_allclose(losses[0], losses[1], rtol=1e-5)
    for a, b in zip(*grads):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
