"""The canonical shapes DMF's compiled programs run on: raster sides and node capacities.

Every raster DMF hands to a compiled program (an NGNEM tile, the support surface) is padded to
one of a few shapes: each axis to one of the canonical sides of the NGNEM's tiling at W
(`canonical_sides`; the vmapped batches of a tiled NGNEM to squares of the largest), every
array of ND_CE to a power-of-two capacity (`power_bucket`) and every array of points to a
canonical capacity (`canonical_capacity`), all of `gfjax.tiling.buckets`: a machine compiles
DMF's programs a handful of times in its life, not once per file size (`gfjax warmup` does it
ahead for the shapes of tiles near square, `warm_shapes`; an elongated raster's compiles on
its first run and is kept). The axes are padded apart because the raster stages cost every
padded cell (bcts_2's 300 x 194 NGNEM: 384 x 256, 0.14 s, against 384 x 384, 0.26 s;
`experiments/dmf_raster_padding.py`).
The stages are unchanged by the padding (padded cells lie outside `inside` or the data's
extent, padded nodes have no neighbours, padded points are sliced off), so the labels are the
same.
"""
from __future__ import annotations

from gfjax.tiling.buckets import canonical_rectangle, canonical_sides, power_bucket
from gfjax.tiling.tiles import Tiling

NODE_MIN_CAPACITY = 1 << 12        # the smallest ND_CE capacity [nodes]
NODE_WARM_MAX_CAPACITY = 1 << 18   # the largest ND_CE capacity `warm` compiles ahead (a 500 m tile at W = 1 m)
WARM_VOXELS_M = (1.0, 2.0)         # the W whose raster sides `warm` compiles (W >= 1 m, whole metres)


def raster_sides(cell_m: float, tiling: Tiling | None = None) -> tuple[int, ...]:
    """The canonical sides [cells] of NGNEM tiles of W = `cell_m` [m]: 128, 192, 256, ... up
    to the largest buffered tile of `tiling` (None: `Tiling()`). A W wider than the tiles (a
    cloud of points hundreds of metres apart) makes each tile's core one cell, as the batched
    stages cut it (`filter._tile_core_px`)."""
    tiling = Tiling() if tiling is None else tiling
    return canonical_sides(max(tiling.tile_size_m, cell_m), tiling.buffer_m, cell_m)


def raster_shape(shape: tuple[int, int], cell_m: float, tiling: Tiling | None = None) -> tuple[int, int]:
    """The padded shape of a raster of `shape` cells: each axis rounded up to the smallest
    canonical side holding it, or, for a raster larger than every canonical side (a
    whole-cloud surface), each axis rounded up to a multiple of the largest side."""
    sides = raster_sides(cell_m, tiling)
    fitted = canonical_rectangle(shape, sides)
    if fitted is not None:
        return fitted
    return tuple(-(-s // sides[-1]) * sides[-1] for s in shape)


def warm_shapes(sides: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    """The padded shapes of rasters near square among canonical `sides` (ascending): each
    square and each rectangle of two neighbouring sides, in both orientations (at most 1.5
    times as long as wide). `gfjax warmup` compiles these; the others a first run compiles."""
    pairs = [(s, s) for s in sides]
    for short, long in zip(sides, sides[1:]):
        pairs += [(short, long), (long, short)]
    return tuple(sorted(pairs))


def node_capacity(n_nodes: int) -> int:
    """The power of two (at least `NODE_MIN_CAPACITY`) holding `n_nodes` ND_CE."""
    return power_bucket(n_nodes, minimum=NODE_MIN_CAPACITY)
