"""Whole surveys: many adjacent files filtered as one, without seams at the file borders.

`index` reads every file once into a catalog (bounds of the points filtered, CRS, units); each
file is then filtered on the survey's own tiling frame, so a point gets the tile, cells and
context it would get if the whole survey were one file (`filtered`, `Runner`): a tiled
method runs each tile of the survey's lattice once from a window gathered across the files
(`lattice`), a method whose labels depend on the whole cloud (CSF) the whole survey at once
when it fits in memory (`fits_whole`), any other method each file with a halo of its
neighbours' points (`halo`); a method's per-cloud estimates are made once for the survey
(`survey_config`). The tiles (or files) can run as tasks on a Dask cluster (`cluster`,
`filter(..., client=...)`). Out of core, a method that does not tile runs the same way on
`pieces` of the survey, each with its halo.
"""
from gfjax.io.cloud import Points
from gfjax.survey.catalog import Catalog, Entry, index
from gfjax.survey.halo import (
    HALO_M,
    Settings,
    filter_file,
    fits_whole,
    halo_region,
    halo_width,
    survey_config,
    survey_settings,
    survey_terrain,
    window,
)
from gfjax.survey.lattice import Pieces, pieces
from gfjax.survey.run import Runner, filter, filtered

__all__ = ["HALO_M", "Catalog", "Settings", "Entry", "Pieces", "Points", "Runner", "filter", "filter_file", "filtered", "fits_whole",
           "halo_region", "halo_width", "index", "pieces", "survey_config", "survey_settings", "survey_terrain", "window"]
