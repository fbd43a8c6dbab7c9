"""The coordinate reference system of a LAS/LAZ file, read through laspy and pyproj.

A LAS file states its CRS in an OGC WKT VLR (required for point formats 6-10) or in GeoTIFF
keys (LAS 1.0-1.3). laspy turns each record into a `pyproj.CRS` (WKT preferred); pyproj
supplies every unit of measure, so no WKT is parsed here. A record that is empty (a blank
WKT, as in PDAL's test file `warsaw_small.las`, or a key directory without keys) or that
pyproj cannot read gives no CRS: the file is read as one without a CRS, and `read_crs` says
why in words, for the commands to tell the user. Two GeoTIFF keys that laspy does not turn
into a CRS still carry units and are read from the key directory: `ProjLinearUnitsGeoKey`
(3076, for user-defined projections) and `VerticalUnitsGeoKey` (4099) /
`VerticalCSTypeGeoKey` (4096), the z unit of 2D CRSs.
"""
from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import laspy
import pyproj
from pyproj.database import get_units_map
from pyproj.exceptions import CRSError

if TYPE_CHECKING:
    import rasterio.crs

    from gfjax.io.cloud import Cloud

PROJ_LINEAR_UNITS_KEY = 3076
VERTICAL_CS_TYPE_KEY = 4096
VERTICAL_UNITS_KEY = 4099
_EPSG_CODES = range(1024, 32767)  # GeoTIFF 1.1: values 1024-32766 are EPSG codes
_BLANK = " \t\r\n\0"


def _crs_records(header: laspy.LasHeader) -> list:
    records = list(header.vlrs)
    if getattr(header, "evlrs", None):
        records += list(header.evlrs)
    return [r for r in records if isinstance(r, (laspy.vlrs.known.WktCoordinateSystemVlr,
                                                 laspy.vlrs.known.GeoKeyDirectoryVlr))]


def read_crs(header: laspy.LasHeader) -> tuple[pyproj.CRS | None, str | None]:
    """The file's CRS (WKT VLR preferred over GeoTIFF keys), or None; and why not, in words.

    Returns:
      `(crs, problem)`: `problem` is None when the file has a CRS or holds no CRS record; when
      it holds CRS records and none gives a CRS, it names them, e.g. "empty WKT CRS record" or
      "unreadable WKT CRS record (Invalid WKT string: garbage)". Such a file is one without a
      CRS. (A key directory of a user-defined projection gives no CRS and is no problem: its
      unit keys still count, `geokey_units_m`.)
    """
    found: dict[str, pyproj.CRS] = {}
    problems = []
    for record in _crs_records(header):
        wkt = isinstance(record, laspy.vlrs.known.WktCoordinateSystemVlr)
        kind = "WKT" if wkt else "GeoTIFF"
        if (wkt and not record.string.strip(_BLANK)) or (not wkt and not any(key.id for key in record.geo_keys)):
            problems.append(f"empty {kind} CRS record")
            continue
        try:
            crs = record.parse_crs()
        except (CRSError, ValueError, UnicodeDecodeError) as err:
            problems.append(f"unreadable {kind} CRS record ({' '.join(str(err).split())})")
            continue
        if crs is not None:
            found.setdefault(kind, crs)
    crs = found.get("WKT", found.get("GeoTIFF"))
    return crs, (None if crs is not None or not problems else "; ".join(problems))


@functools.cache
def _linear_units_by_code() -> dict[int, float]:
    units = get_units_map(auth_name="EPSG", category="linear")
    return {int(u.code): float(u.conv_factor) for u in units.values() if u.code.isdigit()}


def _unit_factor_m(code: int | None) -> float | None:
    if code is None or code not in _EPSG_CODES:
        return None
    return _linear_units_by_code().get(code)


def _geo_keys(header: laspy.LasHeader) -> dict[int, int]:
    """Short-valued GeoTIFF keys (stored in the directory itself) by key id."""
    keys: dict[int, int] = {}
    for record in _crs_records(header):
        if isinstance(record, laspy.vlrs.known.GeoKeyDirectoryVlr):
            for key in record.geo_keys:
                if key.tiff_tag_location == 0:
                    keys[int(key.id)] = int(key.value_offset)
    return keys


def geokey_units_m(header: laspy.LasHeader) -> tuple[float | None, float | None]:
    """Metres per horizontal and per vertical unit stated by GeoTIFF keys (None if absent).

    Horizontal: `ProjLinearUnitsGeoKey`. Vertical: `VerticalUnitsGeoKey`, else the axis unit
    of the EPSG vertical CRS in `VerticalCSTypeGeoKey`.
    """
    keys = _geo_keys(header)
    horizontal_m = _unit_factor_m(keys.get(PROJ_LINEAR_UNITS_KEY))
    vertical_m = _unit_factor_m(keys.get(VERTICAL_UNITS_KEY))
    code = keys.get(VERTICAL_CS_TYPE_KEY)
    if vertical_m is None and code in _EPSG_CODES:
        try:
            vertical_m = float(pyproj.CRS.from_epsg(code).axis_info[0].unit_conversion_factor)
        except (CRSError, IndexError):
            vertical_m = None
    return horizontal_m, vertical_m


def describe(crs: pyproj.CRS | None) -> str:
    """E.g. "WGS 84 / UTM zone 32N (EPSG:32632)", or "none" when there is no CRS."""
    if crs is None:
        return "none"
    authority = crs.to_authority(min_confidence=90)
    return f"{crs.name} ({':'.join(authority)})" if authority else crs.name


def crs_wkt(cloud: Cloud) -> str | None:
    """The cloud's CRS as WKT2 (what GDAL/rasterio accept), or None when it has none."""
    crs = getattr(cloud, "crs", None)
    return None if crs is None else crs.to_wkt()


def rasterio_crs(cloud: Cloud) -> rasterio.crs.CRS | None:
    """The cloud's CRS for `rasterio.open(..., crs=...)` (e.g. the DTM GeoTIFF), or None.

    A compound CRS is kept whole when GDAL accepts it, otherwise its horizontal part is used.
    """
    import rasterio.crs
    from rasterio.errors import CRSError as RasterioCRSError

    crs = getattr(cloud, "crs", None)
    if crs is None:
        return None
    try:
        return rasterio.crs.CRS.from_wkt(crs.to_wkt())
    except RasterioCRSError:
        if crs.is_compound:
            return rasterio.crs.CRS.from_wkt(crs.sub_crs_list[0].to_wkt())
        raise
