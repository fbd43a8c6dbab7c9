"""DMF's canonical raster shapes: each axis padded apart, and the shapes `warm` prepares; the
height rule gives the same labels on any padding of its surface."""
from __future__ import annotations

import numpy as np

from gfjax.dmf import programs, shapes
from gfjax.tiling.tiles import Tiling


def test_each_axis_is_padded_to_its_own_side():
    sides = shapes.raster_sides(1.0)
    assert sides == (128, 192, 256, 384, 512, 640)
    assert shapes.raster_shape((300, 194), 1.0) == (384, 256)        # bcts_2's NGNEM: not 384 x 384
    assert shapes.raster_shape((194, 300), 1.0) == (256, 384)
    assert shapes.raster_shape((10, 10), 1.0) == (128, 128)
    assert shapes.raster_shape((640, 1), 1.0) == (640, 128)
    # larger than every side (a whole-cloud surface): multiples of the largest
    assert shapes.raster_shape((700, 100), 1.0) == (1280, 640)
    assert shapes.raster_shape((100, 40), 1.0, Tiling(tile_size_m=24.0, buffer_m=14.0)) == (128, 64)


def test_warm_shapes_are_the_squares_and_neighbouring_rectangles():
    assert shapes.warm_shapes((128, 192, 256)) == ((128, 128), (128, 192), (192, 128), (192, 192), (192, 256),
                                                   (256, 192), (256, 256))
    assert shapes.warm_shapes((128,)) == ((128, 128),)
    for rows, cols in shapes.warm_shapes(shapes.raster_sides(1.0)):
        assert max(rows, cols) / min(rows, cols) <= 1.5


def test_height_rule_is_the_same_on_any_padding_of_its_surface():
    """The support surface in the south-west corner of a larger raster, its padding filled from
    the data's edges: every point's verdict is the unpadded surface's, points beyond the data's
    extent (clamped) included."""
    rng = np.random.default_rng(0)
    h, w = 30, 20
    surface = rng.normal(100.0, 2.0, (h, w)).astype(np.float32)
    valid = rng.random((h, w)) < 0.3
    points = np.column_stack([rng.uniform(-2.0, w + 2.0, 4096), rng.uniform(-2.0, h + 2.0, 4096),
                              rng.normal(100.0, 2.5, 4096)]).astype(np.float32)
    hw = np.asarray([h, w], np.int32)

    def verdicts(shape):
        s, v = np.zeros(shape, np.float32), np.zeros(shape, bool)
        s[shape[0] - h:, :w], v[shape[0] - h:, :w] = surface, valid
        return np.asarray(programs.height_test(s, v, hw, points, np.float32(1.0), np.float32(0.5)))

    unpadded = verdicts((h, w))
    assert 0.2 < unpadded.mean() < 0.8
    for shape in ((64, 20), (30, 48), (128, 192)):
        np.testing.assert_array_equal(verdicts(shape), unpadded, err_msg=str(shape))
