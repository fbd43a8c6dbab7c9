"""The bucket policy: the sizes every method's padded arrays take, and that folding the
methods' own copies into it moved no size (so no label and no compiled shape)."""
from __future__ import annotations

import math

import pytest

from gfjax.tiling import buckets


# The rules each method wrote for itself before they were folded into `buckets`: the sizes
# its programs were compiled for, which the folded ones must give for every input.
def former_tiles_bucket(n: int, minimum: int = 256) -> int:          # tiles.capacity_bucket
    size = minimum
    while True:
        if n <= size:
            return size
        if n <= size * 3 // 2:
            return size * 3 // 2
        size *= 2


def former_partition_bucket(n: int, min_capacity: int = 256) -> int:   # sparsegf.partition
    if n <= max(min_capacity, 2):
        return max(min_capacity, n)
    j = max(1, math.ceil(math.log2(n)) - 1)
    return 3 * 2 ** (j - 1) if 3 * 2 ** (j - 1) >= n else 2 ** (j + 1)


def former_alpha_shape_bucket(n: int, minimum: int = 1024) -> int:      # masf.alpha_shape.bucket
    size = minimum
    while size < n:
        size = size * 3 // 2 if (size & (size - 1)) == 0 else (size // 3) * 4
    return size


def former_doubling(n: int, minimum: int) -> int:          # sparsegf.pipeline.capacity, dmf.shapes.node_capacity
    size = minimum
    while size < n:
        size *= 2
    return size


COUNTS = [*range(0, 2100), 4095, 4096, 4097, 6143, 6144, 6145, 65_535, 65_537, 98_305, 1_000_003, 5_000_000]


@pytest.mark.parametrize("minimum", [1, 4, 100, 256, 1000, 1024, 4096])
def test_capacity_bucket_is_each_former_rule(minimum):
    for n in COUNTS:
        got = buckets.capacity_bucket(n, minimum=minimum)
        assert got == former_partition_bucket(n, minimum), (n, minimum)
        if minimum & (minimum - 1) == 0:          # the callers of these two used powers of two only
            assert got == former_tiles_bucket(n, minimum), (n, minimum)
        if minimum == 1024:                       # MASF's one minimum (its rule stalls at 1)
            assert got == former_alpha_shape_bucket(n, minimum), (n, minimum)


@pytest.mark.parametrize("minimum", [1, 1024, 4096, 8192, 65_536, 262_144])
def test_power_bucket_is_the_former_doubling(minimum):
    assert all(buckets.power_bucket(n, minimum=minimum) == former_doubling(n, minimum) for n in COUNTS)


def test_capacity_bucket_ladder():
    assert [buckets.capacity_bucket(n, minimum=4) for n in (1, 4, 5, 6, 7, 8, 9, 13, 24, 25)] == \
        [4, 4, 6, 6, 8, 8, 12, 16, 24, 32]
    assert [buckets.capacity_bucket(n, minimum=1024) for n in (0, 1024, 1025, 1537, 5000)] == \
        [1024, 1024, 1536, 2048, 6144]
    for n in range(1, 5000, 37):
        cap = buckets.capacity_bucket(n)
        assert cap >= n and cap >= 256 and (cap <= 256 or cap < 1.5 * n)


def test_buckets():
    assert [buckets.capacity_bucket(n) for n in (1, 256, 257, 385, 1000)] == [256, 256, 384, 512, 1024]
    assert buckets.shape_bucket((1, 600)) == (64, 640)


def test_canonical_sides_and_capacities():
    assert buckets.canonical_sides(500.0, 50.0, 1.0) == (128, 192, 256, 384, 512, 640)
    assert buckets.max_window_px(500.0, 50.0, 1.0) == 601
    assert buckets.canonical_sides(100.0, 10.0, 1.0) == (128,)
    assert buckets.canonical_sides(500.0, 50.0, 0.5) == (128, 192, 256, 384, 512, 768, 1024, 1216)
    assert [buckets.canonical_capacity(n) for n in (1, 16384, 16385, 70_000, 300_000, 4194304, 5_100_000,
                                                   9_000_000)] == \
        [16384, 16384, 65536, 262144, 1048576, 4194304, 8388608, 16777216]     # x2 beyond the largest warmed
    assert buckets.canonical_capacities() == (16384, 65536, 262144, 1048576, 4194304)


def test_canonical_square():
    assert buckets.canonical_square((100, 130), (128, 192)) == (192, 192)
    assert buckets.canonical_square((1, 1), (128, 192)) == (128, 128)
    assert buckets.canonical_square((100, 200), (128, 192)) is None


def test_canonical_side_and_rectangle():
    assert buckets.canonical_side(128, (128, 192)) == 128
    assert buckets.canonical_side(129, (128, 192)) == 192
    assert buckets.canonical_side(193, (128, 192)) is None
    assert buckets.canonical_rectangle((300, 194), (128, 192, 256, 384)) == (384, 256)
    assert buckets.canonical_rectangle((1, 130), (128, 192)) == (128, 192)
    assert buckets.canonical_rectangle((100, 200), (128, 192)) is None
    assert buckets.canonical_rectangle((200, 100), (128, 192)) is None
