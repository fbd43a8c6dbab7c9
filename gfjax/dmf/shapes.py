"""The canonical shapes DMF's compiled programs run on: raster sides and node capacities.

Every raster DMF hands to a compiled program (an NGNEM tile, the support surface) is padded to
a square of one of a few sides (`canonical_sides` of the NGNEM's tiling at W), every array of
ND_CE to a power-of-two capacity (`power_bucket`) and every array of points to a canonical
capacity (`canonical_capacity`), all of `gfjax.tiling.buckets`: a machine compiles DMF's
programs a handful of times in its life, not once per file size (`gfjax warmup` does it
ahead). The stages are
unchanged by the padding (padded cells lie outside `inside` or the data's extent, padded
nodes have no neighbours, padded points are sliced off), so the labels are the same.
"""
from __future__ import annotations

from gfjax.tiling.buckets import canonical_sides, canonical_square, power_bucket
from gfjax.tiling.tiles import Tiling

NODE_MIN_CAPACITY = 1 << 12        # the smallest ND_CE capacity [nodes]
NODE_WARM_MAX_CAPACITY = 1 << 18   # the largest ND_CE capacity `warm` compiles ahead (a 500 m tile at W = 1 m)
WARM_VOXELS_M = (1.0, 2.0)         # the W whose raster sides `warm` compiles (W >= 1 m, whole metres)


def raster_sides(cell_m: float, tiling: Tiling | None = None) -> tuple[int, ...]:
    """The canonical square sides [cells] of NGNEM tiles of W = `cell_m` [m]: 128, 192, 256,
    ... up to the largest buffered tile of `tiling` (None: `Tiling()`). A W wider than the
    tiles (a cloud of points hundreds of metres apart) makes each tile's core one cell, as
    the batched stages cut it (`filter._tile_core_px`)."""
    tiling = Tiling() if tiling is None else tiling
    return canonical_sides(max(tiling.tile_size_m, cell_m), tiling.buffer_m, cell_m)


def raster_shape(shape: tuple[int, int], cell_m: float, tiling: Tiling | None = None) -> tuple[int, int]:
    """The padded shape of a raster of `shape` cells: the smallest canonical square holding it,
    or, for a raster larger than every canonical side (a whole-cloud surface), each axis
    rounded up to a multiple of the largest side."""
    sides = raster_sides(cell_m, tiling)
    square = canonical_square(shape, sides)
    if square is not None:
        return square
    return tuple(-(-s // sides[-1]) * sides[-1] for s in shape)


def node_capacity(n_nodes: int) -> int:
    """The power of two (at least `NODE_MIN_CAPACITY`) holding `n_nodes` ND_CE."""
    return power_bucket(n_nodes, minimum=NODE_MIN_CAPACITY)
