"""CSF's cloth a chunk at a time (`cloth.start` / `advance` / `finish`, `filter`'s progress
bar): the cloth, its stopping step and the labels of the one-program simulation, however the
blocks are cut."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_csf import surface

from gfjax import csf
from gfjax.csf import cloth

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
