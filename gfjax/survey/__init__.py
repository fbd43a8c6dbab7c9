"""Whole surveys: many adjacent files filtered as one, without seams at the file borders.

`index` reads every file once into a catalog (bounds of the points filtered, CRS, units); each
file is then filtered together with a halo of its neighbours' points, on the survey's own
tiling frame, so a point gets the tile, cells and context it would get if the whole survey
were one file (`filtered`); a method's per-cloud estimates are made once for the survey
(`survey_config`).
"""
from gfjax.survey.catalog import Catalog, Entry, index
from gfjax.survey.halo import Points, filter_file, filtered, halo_region, survey_config, window

__all__ = ["Catalog", "Entry", "Points", "filter_file", "filtered", "halo_region", "index", "survey_config",
           "window"]
