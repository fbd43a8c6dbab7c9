"""SMRF's terrain as two per-point inputs of SparseGF's network (feature set `"...+smrf"`).

Per point of a cloud, from SMRF run once over the whole cloud with its defaults and the cell
that follows the cloud's spacing (Pingel et al. 2013; `gfjax.smrf`, `gfjax.smrf.adapt`: a
1 m cell on a 0.06 points/m² forest calls half its ground objects, and the network would
follow it):

- `dz = z - ZIpro(x, y)`: the height over SMRF's provisional ground surface;
- `margin = threshold + scalar * slope(x, y) - |dz|`: SMRF's own final test, >= 0 where SMRF
  calls the point ground;

both bilinear between cell centres, as SMRF's point test samples them, and entered as
`sign(h) log(1 + |h| / 1 m)` like the top-hat heights (`features.signed_log`). Not in the
paper: its network learns the terrain from 542 M labelled points; from a few million the
tiny network gets further by refining a classic filter's surface than by finding the
terrain from coordinates and openings alone (measured in
`experiments/results/sparsegf_eval.md`). Computed on the host before partitioning: the
surface is the cloud's, so a point has one value whichever patch it falls in, and the
rotation and shift augmentations leave it unchanged.
"""
from __future__ import annotations

import numpy as np
import scipy.ndimage
from jaxtyping import Float

from gfjax.io.cloud import Frame

N_SMRF_FEATURES = 2      # the columns of `smrf_heights`: (dz, margin)



def smrf_heights(xyz_m: Float[np.ndarray, "n 3"], frame: Frame | None = None) -> Float[np.ndarray, "n 2"]:
    """`(dz, margin)` `(n, 2)` float32 [m] of every point (module docstring), raw (not logged).

    SMRF runs over the cloud's buffered tiles as `gfjax.smrf.filter` does (groups of points
    far apart each on tiles of its own, `gfjax.tiling.driver.classify_groups`), and each point is
    read off the rasters of the tile whose core holds it, sampled as SMRF's own point test
    samples them. `frame`: the lattice's box (a survey's, whose windows then grid their points
    as the whole survey does: `gfjax.io.cloud.Frame`), None for the points' own."""
    from gfjax import adaptive
    from gfjax.smrf import programs
    from gfjax.smrf.config import MAX_BATCH, Config, Params, adapt
    from gfjax.tiling import driver, tiles
    from gfjax.tiling.checks import lattice_of

    xyz_m = np.asarray(xyz_m, np.float64)
    if len(xyz_m) == 0:
        return np.zeros((0, N_SMRF_FEATURES), np.float32)
    config, params = Config(**adapt(adaptive.measure(xyz_m))), Params()
    lattice = lattice_of(None, config.cell_m)
    use = np.ones(len(xyz_m), bool)
    members = driver.tiled_groups(xyz_m[:, :2], use, lattice, frame)
    if members is None:
        run = driver.classify_cloud(xyz_m, use, programs.classify_batch, params, config, lattice=lattice,
                                   max_batch=MAX_BATCH, frame=frame)
    else:
        run = driver.classify_groups(xyz_m, use, members, programs.classify_batch, params, config, lattice=lattice,
                                    max_batch=MAX_BATCH, keep_diagnostics=True)
    dzs, margins = [], []
    for tile, diag in zip(run.tiles, run.diagnostics):
        h, w = tile.shape
        local = np.asarray(tile.local_xyz)
        u = local[:, 0] / config.cell_m - 0.5                              # fractional column
        v = (h - 0.5) - local[:, 1] / config.cell_m                        # fractional row, row 0 = north

        def at(raster, u=u, v=v):
            return scipy.ndimage.map_coordinates(np.asarray(raster, np.float64), [v, u], order=1, mode="nearest")

        dz = local[:, 2] - at(diag.zipro)
        margin = float(params.threshold_m) + float(params.scalar) * at(diag.slope) - np.abs(dz)
        dzs.append(dz.astype(np.float32))
        margins.append(margin.astype(np.float32))
    n = len(xyz_m)
    return np.stack([tiles.merge(n, run.tiles, dzs), tiles.merge(n, run.tiles, margins)], axis=1)
