"""Linear units of a LAS file: metres per horizontal and per vertical coordinate unit.

Algorithms work in metres. The units come from the file's CRS (read by pyproj, never by
parsing WKT here), or from `--units m|ft|us-ft`; a file without a CRS (or whose CRS record is
empty or unreadable) is taken to be in metres, and the returned `Units` says so
(`assumed`, `source`). Horizontal and vertical units may
differ (a compound CRS such as `EPSG:2994+6360`, international feet over US survey feet, or a
GeoTIFF `VerticalUnitsGeoKey`). A 2D CRS with no vertical information gives z the
horizontal unit, as LAStools and PDAL assume (the Autzen sample is feet in x, y and z).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

from gfjax.errors import InputError

if TYPE_CHECKING:
    import pyproj

METRE_M = 1.0
INTERNATIONAL_FOOT_M = 0.3048
US_SURVEY_FOOT_M = 1200.0 / 3937.0

# `--units` choices -> metres per unit (horizontal and vertical alike).
UNIT_CHOICES: dict[str, float] = {"m": METRE_M, "ft": INTERNATIONAL_FOOT_M, "us-ft": US_SURVEY_FOOT_M}
_NAMES = {METRE_M: "metre", INTERNATIONAL_FOOT_M: "international foot", US_SURVEY_FOOT_M: "US survey foot"}


class Units(NamedTuple):
    """Metres per coordinate unit, and where that came from.

    Attributes:
      horizontal_m: metres per x/y unit (1.0, 0.3048, 1200/3937, ...).
      vertical_m: metres per z unit.
      source: human-readable origin, e.g. "CRS", "--units ft", "no CRS in file: metres assumed".
      assumed: True when nothing stated the units (no usable CRS, no unit keys, no `--units`)
        and metres were assumed; the commands say so once per run.
    """

    horizontal_m: float
    vertical_m: float
    source: str
    assumed: bool = False


class UnusableUnits(InputError):
    """A CRS whose horizontal axes have no linear unit (a geographic CRS in degrees): the
    filters cannot work in metres. `reason` is the message without the file name."""

    def __init__(self, name: str, reason: str):
        super().__init__(f"{name}: {reason}")
        self.reason = reason


def snap_factor(factor_m: float) -> float:
    """`factor_m`, replaced by the exact constant of a known unit when within 1e-9 relative.

    pyproj stores the US survey foot as 0.304800609601219; this returns 1200/3937 exactly.
    """
    for known in _NAMES:
        if math.isclose(factor_m, known, rel_tol=1e-9):
            return known
    return float(factor_m)


def unit_name(factor_m: float) -> str:
    """"metre", "international foot", "US survey foot", or "unit of <f> m"."""
    return _NAMES.get(snap_factor(factor_m), f"unit of {factor_m:g} m")


def parse_units_option(text: str) -> Units:
    """`--units m|ft|us-ft` as `Units` (the same factor horizontally and vertically)."""
    if text not in UNIT_CHOICES:
        raise InputError(f"--units: unknown unit {text!r}; choose from {', '.join(UNIT_CHOICES)}")
    factor = UNIT_CHOICES[text]
    return Units(factor, factor, f"--units {text}")


def _linear_factor(crs: pyproj.CRS, axis_index: int, *, name: str) -> float:
    axis = crs.axis_info[axis_index]
    if crs.is_geographic and axis_index < 2:
        raise UnusableUnits(name, f"the CRS {crs.name!r} is geographic (degrees); ground filters need a "
                                  "projected CRS in metres or feet: reproject the file, or pass --units")
    factor = axis.unit_conversion_factor
    if not (factor > 0.0 and math.isfinite(factor)):
        raise UnusableUnits(name, f"CRS axis {axis.name!r} has no usable linear unit ({axis.unit_name!r})")
    return snap_factor(factor)


def units_from_crs(crs: pyproj.CRS | None, *, name: str, horizontal_unit_m: float | None = None,
                   vertical_unit_m: float | None = None, crs_problem: str | None = None) -> Units:
    """The units of a file whose CRS is `crs` (None and no GeoTIFF units: metres assumed).

    Args:
      crs: the file's CRS (2D projected, 3D, or compound horizontal + vertical), or None.
      name: the file, for error messages.
      horizontal_unit_m: metres per x/y unit from GeoTIFF `ProjLinearUnitsGeoKey`, used only
        when `crs` is None (a user-defined projection that pyproj could not build).
      vertical_unit_m: metres per z unit from GeoTIFF `VerticalUnitsGeoKey` or
        `VerticalCSTypeGeoKey`, used when `crs` has no vertical axis.
      crs_problem: why the file's CRS records gave no CRS (`gfjax.io.crs.read_crs`), or None
        when it holds none; `source` then says "no usable CRS" rather than "no CRS".

    Raises:
      UnusableUnits: a geographic CRS (degrees), or an axis without a linear unit.
    """
    if crs is None:
        if horizontal_unit_m is None and vertical_unit_m is None:
            source = "no CRS in file" if crs_problem is None else "no usable CRS in file"
            return Units(METRE_M, METRE_M, f"{source}: metres assumed", assumed=True)
        h_m = snap_factor(horizontal_unit_m) if horizontal_unit_m is not None else METRE_M
        v_m = snap_factor(vertical_unit_m) if vertical_unit_m is not None else h_m
        return Units(h_m, v_m, "GeoTIFF unit keys (no full CRS)")
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    horizontal_m = _linear_factor(horizontal, 0, name=name)
    if crs.is_compound and len(crs.sub_crs_list) > 1:
        return Units(horizontal_m, _linear_factor(crs.sub_crs_list[1], 0, name=name), "CRS (compound)")
    if len(crs.axis_info) >= 3:
        return Units(horizontal_m, _linear_factor(crs, 2, name=name), "CRS (3D)")
    if vertical_unit_m is not None:
        return Units(horizontal_m, snap_factor(vertical_unit_m), "CRS; vertical unit from GeoTIFF keys")
    return Units(horizontal_m, horizontal_m, "CRS; no vertical CRS: z in the horizontal unit")


def describe(units: Units) -> str:
    """One line, e.g. "horizontal international foot (0.3048 m), vertical ... [CRS]"."""
    return (f"horizontal {unit_name(units.horizontal_m)} ({units.horizontal_m:.12g} m), "
            f"vertical {unit_name(units.vertical_m)} ({units.vertical_m:.12g} m) [{units.source}]")
