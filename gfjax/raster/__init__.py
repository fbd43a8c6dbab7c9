"""Raster kernels: pure JAX, jit-able, correct under `jax.vmap`, no scipy.

Every function takes one tile (no batch axis); static arguments are keyword-only; empty cells
are carried by a `valid` mask, never NaN. Row 0 of a raster is its northern edge (see
`gfjax.raster.grid`). The contract is `docs/ARCHITECTURE.md`, section "Raster kernels".
"""
from gfjax.raster.fill import fill_holes, inpaint_harmonic, inpaint_nearest, nearest_valid_index, solve_harmonic
from gfjax.raster.grid import cell_index, domain_mask, replicate_edges, sample_bilinear
from gfjax.raster.label import RingStats, boundary_ring, label_components, relabel_consecutive
from gfjax.raster.morphology import (
    chord_half_widths,
    closing,
    dilate,
    disk,
    erode,
    max_filter,
    min_filter,
    opening,
)
from gfjax.raster.rasterize import CellStats, flat_cell, rasterize

__all__ = [
    "cell_index", "domain_mask", "replicate_edges", "sample_bilinear", "CellStats", "rasterize", "flat_cell",
    "inpaint_nearest", "inpaint_harmonic", "solve_harmonic", "nearest_valid_index", "fill_holes",
    "disk", "chord_half_widths", "min_filter", "max_filter", "erode", "dilate", "opening", "closing",
    "label_components", "relabel_consecutive", "RingStats", "boundary_ring",
]
