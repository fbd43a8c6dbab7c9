"""How large a padded array is: the bucket policy of every method's compiled programs.

A jitted program compiles once per input shape, so everything padded for one (a tile's
points, its raster, a method's nodes, triangles or voxels) is padded to one of a few sizes
chosen here, outside jit, from the data: a machine compiles each program a handful of times
in its life, not once per input size. Padding is always masked (`valid`, `inside`) or sliced
off, so it changes no label.

- `capacity_bucket`: the ladder 1, 2, 3, 4, 6, 8, 12, ... (`2^k` and `1.5 * 2^k`), at least a
  minimum: at most half as many slots again as items (tuning's batches, small windows, CSF's
  tuning samples, SparseGF's patches, MASF's triangles).
- `power_bucket`: the minimum times a power of two (DMF's ND_CE, SparseGF's packs and patches).
- `canonical_capacity` / `canonical_capacities`: point capacities in powers of 4, the few a
  filter's windows are padded to and `gfjax warmup` compiles ahead.
- `tile_capacity` / `tile_capacities`: a tiled method's windows, padded as `canonical_capacity`
  up to `POINT_CHUNK` points, to whole chunks above it (`gfjax.tiling.chunks` runs them a
  chunk at a time).
- `canonical_sides`, `shape_bucket`: raster sides of a tiling's windows.

Plain integer arithmetic (no numpy, no JAX): a layer below any array code may use it.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["capacity_bucket", "power_bucket", "canonical_capacity", "canonical_capacities", "tile_capacity",
           "tile_capacities", "canonical_sides", "canonical_side", "canonical_square", "canonical_rectangle",
           "shape_bucket", "max_window_px", "check_lattice"]

MIN_CAPACITY = 256
SHAPE_QUANTUM_PX = 64
SMALLEST_SIDE_PX = 128        # the smallest canonical raster side (`canonical_sides`)
SMALL_SIDES_PX = (8, 16, 32, 64)   # the sides of `batches.small_batches`, below the canonical ones
CANONICAL_MIN_CAPACITY = 1 << 14
CANONICAL_MAX_CAPACITY = 1 << 22   # the largest capacity `gfjax warmup` compiles ahead
# The most points a tiled method's point programs take in one call: a larger window runs a chunk
# at a time (`gfjax.tiling.chunks`), so their temporaries stay those of a chunk (tens of MB).
POINT_CHUNK = 1 << 20


def check_lattice(tile_size_m: float, buffer_m: float, cell_m: float) -> None:
    """Raise `ValueError` unless a tiling of `tile_size_m`, `buffer_m` at a cell of `cell_m` [m] is
    valid: a positive cell, a core of at least one cell, a buffer >= 0."""
    if not (math.isfinite(cell_m) and cell_m > 0):
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    if not (math.isfinite(tile_size_m) and tile_size_m >= cell_m):
        raise ValueError(f"tile_size_m must be >= cell_m ({cell_m}), got {tile_size_m}")
    if not (math.isfinite(buffer_m) and buffer_m >= 0):
        raise ValueError(f"buffer_m must be >= 0, got {buffer_m}")


def capacity_bucket(n: int, *, minimum: int = MIN_CAPACITY) -> int:
    """The smallest of `minimum` and the ladder `2^k`, `1.5 * 2^k` (1, 2, 3, 4, 6, 8, 12, ...)
    holding `n` items: few shapes ever compile, and at most half the slots are padding above
    the minimum. The ladder does not depend on `minimum`, so callers with different minimums
    share its sizes."""
    if n <= minimum:
        return minimum
    high = 1 << (n - 1).bit_length()          # the smallest power of two >= n
    three = 3 * high // 4                     # 1.5 times the power of two below it
    return three if three >= n else high


def power_bucket(n: int, *, minimum: int) -> int:
    """The smallest `minimum * 2^k` holding `n` items: fewer sizes than `capacity_bucket`, at
    most twice the items, for programs that are costly to compile."""
    size = minimum
    while size < n:
        size *= 2
    return size


def shape_bucket(shape: tuple[int, int], *, quantum_px: int = SHAPE_QUANTUM_PX) -> tuple[int, int]:
    """Raster shape rounded up to a multiple of `quantum_px` rows and columns."""
    return tuple(int(-(-s // quantum_px) * quantum_px) for s in shape)


def max_window_px(tile_size_m: float, buffer_m: float, cell_m: float) -> int:
    """The largest side [cells] a buffered window of `tiles.split` can have (a core snapped
    outwards to the lattice, plus a buffer each side)."""
    return math.ceil(tile_size_m / cell_m - 1e-9) + 1 + 2 * math.ceil(buffer_m / cell_m - 1e-9)


def canonical_sides(tile_size_m: float, buffer_m: float, cell_m: float) -> tuple[int, ...]:
    """The square raster sides [cells] every window of this tiling is padded to: 128, 192,
    256, 384, 512, ... (2^k and 1.5 * 2^k) below the largest window, and the largest window
    rounded up to `SHAPE_QUANTUM_PX` (128, 192, 256, 384, 512, 640 for 500 m tiles, 50 m
    buffers and 1 m cells). Padding a window to the next side costs at most 2.25 times its
    cells (more for a thin strip), far less than compiling a raster program for each new
    window size (`experiments/results/canonical_shapes.md`)."""
    check_lattice(tile_size_m, buffer_m, cell_m)
    largest = shape_bucket((max_window_px(tile_size_m, buffer_m, cell_m),) * 2)[0]
    sides, side = [], SMALLEST_SIDE_PX
    while side < largest:
        sides.append(side)
        if side * 3 // 2 < largest:
            sides.append(side * 3 // 2)
        side *= 2
    return (*sides, largest)


def canonical_capacities() -> tuple[int, ...]:
    """Point capacities `warmup` compiles: `CANONICAL_MIN_CAPACITY` times powers of 4 up to
    `CANONICAL_MAX_CAPACITY` (larger windows still run, at capacities compiled on demand)."""
    caps, cap = [], CANONICAL_MIN_CAPACITY
    while cap <= CANONICAL_MAX_CAPACITY:
        caps.append(cap)
        cap *= 4
    return tuple(caps)


def canonical_capacity(n: int) -> int:
    """Smallest `CANONICAL_MIN_CAPACITY * 4^k` holding `n` points, then powers of 2 beyond
    `CANONICAL_MAX_CAPACITY` (compiled on demand anyway: there the padding's memory counts
    more than a compile, a 5 M-point window padded to 8 M points, not 16 M)."""
    cap = CANONICAL_MIN_CAPACITY
    while cap < n:
        cap *= 4 if cap < CANONICAL_MAX_CAPACITY else 2
    return cap


def tile_capacity(n: int) -> int:
    """The point capacity of a tiled method's window of `n` points: `canonical_capacity` up to
    `POINT_CHUNK`, then whole chunks (a 5.1 M-point window padded to 6 M slots, not 8 M)."""
    if n <= POINT_CHUNK:
        return canonical_capacity(n)
    return -(-n // POINT_CHUNK) * POINT_CHUNK


def tile_capacities() -> tuple[int, ...]:
    """The capacities a tiled method's programs ever run at (`tile_capacity`, chunks included):
    the canonical ones up to `POINT_CHUNK`."""
    return tuple(cap for cap in canonical_capacities() if cap <= POINT_CHUNK)


def canonical_side(n: int, sides: Sequence[int]) -> int | None:
    """The smallest of `sides` (ascending) holding `n` cells, or None when none does."""
    return next((s for s in sides if s >= n), None)


def canonical_square(shape: tuple[int, int], sides: Sequence[int]) -> tuple[int, int] | None:
    """The smallest square of `sides` holding a raster of `shape`, or None when none does."""
    side = canonical_side(max(shape), sides)
    return None if side is None else (side, side)


def canonical_rectangle(shape: tuple[int, int], sides: Sequence[int]) -> tuple[int, int] | None:
    """Each axis of a raster of `shape` rounded up to the smallest of `sides` holding it, or
    None when an axis is longer than every side."""
    rows, cols = canonical_side(shape[0], sides), canonical_side(shape[1], sides)
    return None if rows is None or cols is None else (rows, cols)
