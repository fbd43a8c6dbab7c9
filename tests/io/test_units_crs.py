"""CRS and unit factors of LAS files: real samples, compound CRSs, GeoTIFF keys, overrides."""
from __future__ import annotations

import laspy
import numpy as np
import pyproj
import pytest
from conftest import shared_file
from laspy.vlrs.geotiff import GeoKeyEntryStruct
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

from gfjax.data import demo_sample
from gfjax.errors import InputError
from gfjax.io import crs as crs_lib
from gfjax.io import las as las_io
from gfjax.io import units

US_FT = 1200.0 / 3937.0


def _las_file(path, *, crs=None, version="1.4", point_format=6, vlrs=()):
    header = laspy.LasHeader(point_format=point_format, version=version)
    if crs is not None:
        header.add_crs(crs)
    for vlr in vlrs:
        header.vlrs.append(vlr)
    las = laspy.LasData(header)
    las.x, las.y, las.z = [1.0, 2.0], [3.0, 4.0], [5.0, 6.0]
    las.write(path)
    return path


def _geokeys(*keys: tuple[int, int]) -> GeoKeyDirectoryVlr:
    directory = GeoKeyDirectoryVlr()
    for key_id, value in keys:
        entry = GeoKeyEntryStruct()
        entry.id, entry.tiff_tag_location, entry.count, entry.value_offset = key_id, 0, 1, value
        directory.geo_keys.append(entry)
    directory.geo_keys_header.number_of_keys = len(keys)
    return directory


def _add_geokey(header: laspy.LasHeader, key_id: int, value: int) -> None:
    directory = header.vlrs.get("GeoKeyDirectoryVlr")[0]
    entry = GeoKeyEntryStruct()
    entry.id, entry.tiff_tag_location, entry.count, entry.value_offset = key_id, 0, 1, value
    directory.geo_keys.append(entry)
    directory.geo_keys_header.number_of_keys += 1


@pytest.mark.data
def test_autzen_is_in_international_feet():
    cloud = las_io.read(shared_file("pdal_autzen/autzen_trim.laz"))
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (0.3048, 0.3048)
    assert "no vertical CRS" in cloud.units_source
    np.testing.assert_array_equal(cloud.xyz_m, cloud.xyz * 0.3048)
    assert crs_lib.rasterio_crs(cloud).linear_units == "foot"


def test_isprs_is_utm_32n_in_metres():
    cloud = las_io.read(demo_sample())                      # ISPRS sample 12, shipped in gfjax
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (1.0, 1.0)
    assert cloud.crs.to_epsg() == 32632
    assert crs_lib.describe(cloud.crs) == "WGS 84 / UTM zone 32N (EPSG:32632)"
    assert crs_lib.rasterio_crs(cloud).to_epsg() == 32632


@pytest.mark.data
def test_bcts_vertical_unit_from_geotiff_keys():
    cloud = las_io.read(shared_file("lasR_bcts/bcts_1.laz"))  # EPSG:3005 + VerticalCSType 5713
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (1.0, 1.0)
    assert "GeoTIFF" in cloud.units_source


def test_compound_crs_feet_over_us_survey_feet(tmp_path):
    crs = pyproj.CRS("EPSG:2994+6360")  # Oregon GIC Lambert (ft) + NAVD88 height (ftUS)
    cloud = las_io.read(_las_file(tmp_path / "c.las", crs=crs))
    assert cloud.horizontal_unit_m == 0.3048
    assert cloud.vertical_unit_m == US_FT  # exactly 1200/3937, not pyproj's rounded value
    assert cloud.units_source == "CRS (compound)"
    np.testing.assert_allclose(cloud.xyz_m[:, 2], cloud.xyz[:, 2] * US_FT, rtol=1e-15)
    assert crs_lib.rasterio_crs(cloud) is not None


def test_vertical_units_geokey_differs_from_horizontal(tmp_path):
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.add_crs(pyproj.CRS.from_epsg(2994))
    _add_geokey(header, crs_lib.VERTICAL_UNITS_KEY, 9003)  # US survey foot
    las = laspy.LasData(header)
    las.x, las.y, las.z = [1.0], [2.0], [3.0]
    las.write(tmp_path / "gk.las")
    cloud = las_io.read(tmp_path / "gk.las")
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (0.3048, US_FT)


def test_user_defined_projection_units_from_geokeys(tmp_path):
    directory = _geokeys((1024, 1), (3072, 32767), (3076, 9002))  # user-defined PCS in feet
    path = _las_file(tmp_path / "u.las", version="1.2", point_format=1, vlrs=[directory])
    cloud = las_io.read(path)
    assert cloud.crs is None
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (0.3048, 0.3048)
    found = las_io.header_crs_units(las_io.read_header(path), name=str(path))
    assert found.crs_problem is None and not found.units.assumed


def test_no_crs_defaults_to_metres_and_says_so(tmp_path):
    cloud = las_io.read(_las_file(tmp_path / "n.las"))
    assert cloud.crs is None and crs_lib.crs_wkt(cloud) is None and crs_lib.rasterio_crs(cloud) is None
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (1.0, 1.0)
    assert cloud.units_source == "no CRS in file: metres assumed"
    found = las_io.header_crs_units(las_io.read_header(tmp_path / "n.las"), name="n.las")
    assert found.units.assumed and found.crs_problem is None
    assert not las_io.header_units(las_io.read_header(tmp_path / "n.las"), name="n.las", units="m").assumed


@pytest.mark.parametrize("option,factor", [("m", 1.0), ("ft", 0.3048), ("us-ft", US_FT)])
def test_units_option_overrides_the_crs(tmp_path, option, factor):
    path = _las_file(tmp_path / "o.las", crs=pyproj.CRS.from_epsg(32632))
    cloud = las_io.read(path, units=option)
    assert (cloud.horizontal_unit_m, cloud.vertical_unit_m) == (factor, factor)
    assert cloud.units_source == f"--units {option}"
    assert cloud.crs.to_epsg() == 32632


def test_unknown_units_option(tmp_path):
    with pytest.raises(InputError, match="--units: unknown unit 'yards'; choose from m, ft, us-ft"):
        las_io.read(_las_file(tmp_path / "o.las"), units="yards")


def test_geographic_crs_needs_units(tmp_path):
    path = _las_file(tmp_path / "g.las", crs=pyproj.CRS.from_epsg(4326))
    with pytest.raises(InputError, match=r"g\.las: the CRS 'WGS 84' is geographic \(degrees\)"):
        las_io.read(path)
    assert las_io.read(path, units="m").horizontal_unit_m == 1.0


# CRS records that give no CRS: the file is read as one without a CRS, and says why.
EMPTY_OR_UNREADABLE = {
    "empty WKT": ([WktCoordinateSystemVlr("")], "1.4", 6, "empty WKT CRS record"),
    "blank WKT": ([WktCoordinateSystemVlr(" \n")], "1.4", 6, "empty WKT CRS record"),
    "broken WKT": ([WktCoordinateSystemVlr('PROJCS["broken')], "1.4", 6, "unreadable WKT CRS record (Invalid projection"),
    "not WKT": ([WktCoordinateSystemVlr("garbage")], "1.4", 6, "unreadable WKT CRS record (Invalid WKT string: garbage)"),
    "no GeoTIFF keys": ([_geokeys()], "1.2", 1, "empty GeoTIFF CRS record"),
    "unknown EPSG code": ([_geokeys((1024, 1), (3072, 9999))], "1.2", 1, "unreadable GeoTIFF CRS record"),
}


@pytest.mark.parametrize("case", list(EMPTY_OR_UNREADABLE))
def test_empty_or_unreadable_crs_record_is_no_crs(tmp_path, case):
    vlrs, version, point_format, problem = EMPTY_OR_UNREADABLE[case]
    path = _las_file(tmp_path / "w.las", vlrs=vlrs, version=version, point_format=point_format)
    found = las_io.header_crs_units(las_io.read_header(path), name=str(path))
    assert found.crs is None and found.crs_problem.startswith(problem)
    assert found.units.assumed and (found.units.horizontal_m, found.units.vertical_m) == (1.0, 1.0)
    cloud = las_io.read(path)
    assert cloud.crs is None and cloud.units_source == "no usable CRS in file: metres assumed"
    cloud = las_io.read(path, units="ft")
    assert cloud.crs is None and cloud.horizontal_unit_m == 0.3048


def test_unreadable_wkt_beside_good_geotiff_keys(tmp_path):
    path = _las_file(tmp_path / "w.las", version="1.2", point_format=1,
                     vlrs=[WktCoordinateSystemVlr("garbage"), _geokeys((1024, 1), (3072, 32632))])
    found = las_io.header_crs_units(las_io.read_header(path), name=str(path))
    assert found.crs.to_epsg() == 32632 and found.crs_problem is None and not found.units.assumed


def test_unit_helpers():
    assert units.snap_factor(0.304800609601219) == US_FT
    assert units.snap_factor(0.3048001) == 0.3048001  # 3e-7 apart: not snapped
    assert [units.unit_name(f) for f in (1.0, 0.3048, 0.304800609601219, 0.2)] == [
        "metre", "international foot", "US survey foot", "unit of 0.2 m"]
    text = units.describe(units.Units(0.3048, US_FT, "CRS (compound)"))
    assert text.startswith("horizontal international foot (0.3048 m), vertical US survey foot")
