"""Raster windows: every cell in one core, windows clipped to the raster, full batches, and a
program that reads its window pasted back cell for cell."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from gfjax.tiling import windows

CASES = [((50, 70), 16, 5), ((16, 16), 16, 3), ((1, 33), 8, 8), ((9, 9), 4, 0), ((5, 5), 9, 2)]


@pytest.mark.parametrize("shape, core_px, buffer_px", CASES, ids=str)
def test_every_cell_in_exactly_one_core_and_in_its_window(shape, core_px, buffer_px):
    h, w = shape
    count = np.zeros(shape, int)
    for win in windows.raster_windows(shape, core_px=core_px, buffer_px=buffer_px):
        (r0, r1), (c0, c1) = win.core_rows, win.core_cols
        count[r0:r1, c0:c1] += 1
        (a, b), (c, d) = win.rows, win.cols
        assert a == max(0, r0 - buffer_px) and b == min(h, r0 + core_px + buffer_px)
        assert c == max(0, c0 - buffer_px) and d == min(w, c0 + core_px + buffer_px)
        assert a <= r0 < r1 <= b and c <= c0 < c1 <= d
    np.testing.assert_array_equal(count, 1)


def test_bad_sizes_raise():
    with pytest.raises(ValueError, match="core_px"):
        windows.raster_windows((4, 4), core_px=0, buffer_px=1)
    with pytest.raises(ValueError, match="max_batch"):
        windows.run_windows((4, 4), [], lambda w: (), lambda: None, names={}, max_batch=0)


class Out(NamedTuple):
    value: np.ndarray
    seen: np.ndarray


@pytest.mark.parametrize("shape, core_px, buffer_px", CASES, ids=str)
def test_run_windows_pastes_each_core_and_fills_every_batch(shape, core_px, buffer_px):
    """A program that returns its input (and the window's own cells) gives back the raster."""
    raster = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    found = windows.raster_windows(shape, core_px=core_px, buffer_px=buffer_px)
    side = core_px + 2 * buffer_px
    calls = []

    def tile_of(win):
        (a, b), (c, d) = win.rows, win.cols
        tile = np.full((side, side), -1.0, np.float32)
        tile[:b - a, :d - c] = raster[a:b, c:d]
        return (tile,)

    def run_batch(tiles):
        calls.append(tiles.shape)
        return Out(value=tiles, seen=tiles >= 0)

    rasters, outputs = windows.run_windows(shape, found, tile_of, run_batch,
                                           names={"value": np.float32, "seen": bool}, max_batch=3)
    np.testing.assert_array_equal(rasters["value"], raster)
    assert rasters["seen"].all()
    assert calls == [(3, side, side)] * -(-len(found) // 3)
    assert [n for _, n in outputs] == [min(3, len(found) - s) for s in range(0, len(found), 3)]
