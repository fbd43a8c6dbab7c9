"""CSF's cloth a chunk at a time (`cloth.start` / `advance` / `finish`, `filter`'s progress
bar): the cloth, its stopping step and the labels of the one-program simulation, however the
blocks are cut."""
from __future__ import annotations

import functools
import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_csf import FAST, scene, surface

from gfjax import csf
from gfjax.csf import cloth
from gfjax.io import las
from gfjax.io.cloud import Cloud

filter_module = importlib.import_module("gfjax.csf.filter")
programs = importlib.import_module("gfjax.csf.programs")

# (surface, start above its top [m], time step, cap): settling by the displacement rule, a
# cloth stopped by the cap, one resting everywhere at once (no movable particle), and a time
# step too small to move it (the fixed point of two still steps in a row)
CLOTHS = [("box", 0.05, 0.65, 300), ("ramp", 0.05, 0.65, 300), ("terrace", 0.05, 0.65, 300),
          ("box", 0.05, 0.65, 4), ("flat", 0.05, 0.65, 300), ("box", 0.05, 1e-6, 100_000)]


def _heights(kind: str) -> np.ndarray:
    return np.zeros((9, 13), np.float32) if kind == "flat" else surface(kind)


def _chunked(heights, start_u, time_step, config, chunk):
    """`simulate` as `start`, `advance` by `chunk` blocks (None: one call) until stopped, `finish`."""
    run = cloth.start(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(start_u),
                      jnp.float32(time_step), config=config)
    calls = 0
    while not bool(run.carry.stopped):
        until = cloth.NO_LIMIT if chunk is None else int(run.block) + chunk
        run = cloth.advance(run, jnp.int32(until), config=config)
        calls += 1
    return cloth.finish(run), int(run.block), calls


@pytest.mark.parametrize("case", CLOTHS, ids=str)
def test_the_cloth_is_the_same_however_its_blocks_are_cut(case):
    kind, above, time_step, cap = case
    heights = _heights(kind)
    start_u, config = float(heights.max()) + above, csf.Config(iterations=cap)
    whole = cloth.simulate(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(start_u),
                           jnp.float32(time_step), config=config)
    shape = heights.shape
    for chunk in (None, 1, 2, 7):
        state, blocks, calls = _chunked(heights, start_u, time_step, config, chunk)
        for name in cloth.ClothState._fields:
            np.testing.assert_array_equal(np.asarray(getattr(state, name)), np.asarray(getattr(whole, name)), name)
        # a stop at the cap takes `blocks_to_cap` blocks; the last block finishes the last step
        steps = int(whole.steps)
        assert blocks == steps + cloth.layout(shape).last_group
        assert cloth.steps_done(blocks, shape, iterations=cap) == steps
        assert cloth.steps_done(blocks - 1, shape, iterations=cap) == steps - 1
        assert calls == (1 if chunk is None else -(-blocks // chunk))
    if cap == 4:
        assert int(whole.steps) == 4 and blocks == cloth.blocks_to_cap(shape, iterations=cap)



def test_a_stopped_run_advances_no_further():
    heights = surface("box")
    config = csf.Config(iterations=300)
    run = cloth.start(jnp.asarray(heights), jnp.ones(heights.shape, bool), jnp.float32(heights.max() + 0.05),
                      jnp.float32(0.65), config=config)
    run = cloth.advance(run, jnp.int32(cloth.NO_LIMIT), config=config)
    again = cloth.advance(run, jnp.int32(cloth.NO_LIMIT), config=config)
    for a, b in zip(jax.tree.leaves(run), jax.tree.leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.fixture
def one_block_chunks(monkeypatch):
    """A progress bar's run one block per call: the most cuts a run can have."""
    monkeypatch.setattr(programs, "CHUNK_SLOTS", 1)


def _one_program(monkeypatch):
    """`filter` as it was before the chunks: the whole simulation one program (`drop_cloth`)."""
    monkeypatch.setattr(filter_module, "drop_cloth_in_chunks", lambda surface, params, *, config, progress=False:
                        programs.drop_cloth(surface, params, config=config))


def _same(a, b):
    np.testing.assert_array_equal(a.ground, b.ground)
    for name in ("cloth_z", "surface_z", "movable", "steps", "origin_m"):
        np.testing.assert_array_equal(getattr(a.diagnostics, name), getattr(b.diagnostics, name), name)


@pytest.mark.parametrize("config", [FAST, csf.Config(iterations=6)], ids=["settles", "cap"])
def test_filter_with_a_bar_labels_as_the_one_program_and_says_where_it_stopped(config, one_block_chunks,
                                                                               monkeypatch, capsys):
    cloud = Cloud.from_xyz(scene("plane_box", seed=4) + [3e5, 4e6, 0.0])
    shown = csf.filter(cloud, config=config, progress=True)
    bar = capsys.readouterr().err
    quiet = csf.filter(cloud, config=config)
    assert capsys.readouterr().err == ""                          # progress=False draws nothing
    with monkeypatch.context() as patch:
        _one_program(patch)
        whole = csf.filter(cloud, config=config)
    _same(shown, whole)
    _same(quiet, whole)
    steps, cap = shown.diagnostics.steps, config.iterations
    assert "csf cloth" in bar and "block" in bar
    last = bar.replace("\r", "\n").strip().splitlines()[-1]
    if steps < cap:
        assert f"settled at step {steps}/{cap}" in last and "100%" in last
    else:
        assert f"step {cap}/{cap}" in last and "100%" in last and "settled" not in bar


def test_a_disabled_bar_still_runs_to_the_stop(one_block_chunks, monkeypatch, capsys):
    """`-q` (TQDM_DISABLE): the bar counts nothing, the chunks go on to the cloth's stop."""
    import tqdm.auto

    monkeypatch.setattr(tqdm.auto, "tqdm", functools.partial(tqdm.auto.tqdm, disable=True))
    cloud = Cloud.from_xyz(scene("terrace", seed=2))
    quiet = csf.filter(cloud, config=FAST, progress=True)
    assert capsys.readouterr().err == ""
    _same(quiet, csf.filter(cloud, config=FAST))


@pytest.mark.data
@pytest.mark.parametrize("name", ["samp24"])
def test_labels_on_isprs_samples_are_the_one_program_labels(name, one_block_chunks, monkeypatch):
    """On real samples with the default settings (the trend taken off, a soft cloth), a bar's
    run of one block per call and a run without one give the labels, cloth and stopping step
    of the whole simulation as one program (`drop_cloth`, the program before the chunks)."""
    from conftest import shared_file

    cloud = las.read(shared_file(f"isprs_filtertest/reference/{name}-utm.laz"))
    shown, quiet = csf.filter(cloud, progress=True), csf.filter(cloud)
    with monkeypatch.context() as patch:
        _one_program(patch)
        whole = csf.filter(cloud)
    _same(shown, whole)
    _same(quiet, whole)
    assert 0 < shown.diagnostics.steps < csf.Config().iterations and shown.ground.any()
