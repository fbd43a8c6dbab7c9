"""DTM GeoTIFF: rasterio round trip (values, transform, nodata, CRS), atomic writes, PNG."""
from __future__ import annotations

import matplotlib.image
import numpy as np
import pytest
import rasterio
from rasterio.transform import Affine

import gfjax.dtm
import gfjax.io.las
from gfjax.data import demo_sample
from gfjax.dtm.geotiff import write_geotiff
from gfjax.errors import InputError


@pytest.fixture(scope="module")
def samp12_dtm():
    cloud = gfjax.io.las.read(demo_sample())                # ISPRS sample 12, shipped in gfjax
    return gfjax.dtm.build(cloud, cloud.classification == 2, cell_m=1.0)


def _read(path):
    with rasterio.open(path) as src:
        return src.read(1), src.profile, src.crs, src.transform, src.block_shapes


def test_geotiff_round_trip_samp12(samp12_dtm, tmp_path):
    dtm = samp12_dtm
    assert dtm.crs.to_epsg() == 32632
    assert 0.9 < dtm.valid.mean() < 1.0                    # a few border cells stay nodata
    out = tmp_path / "dtm.tif"
    dtm.to_geotiff(out)
    z, profile, crs, transform, blocks = _read(out)
    assert crs.to_epsg() == 32632
    assert transform == dtm.transform and transform.a == 1.0 and transform.e == -1.0
    assert profile["nodata"] == -9999.0 and profile["dtype"] == "float32"
    assert profile["compress"] == "deflate"
    assert max(dtm.shape) > 256 and blocks == [(256, 256)]      # tiled
    with rasterio.open(out) as src:                             # cloud-optimised: overviews, COG layout
        assert src.tags(ns="IMAGE_STRUCTURE")["LAYOUT"] == "COG" and src.overviews(1)
        assert src.tags(ns="IMAGE_STRUCTURE")["PREDICTOR"] == "3"
    np.testing.assert_array_equal(z, dtm.z.astype(np.float32))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dtm.tif"]   # no temporary left


def test_small_geotiff_without_crs(tmp_path):
    z = np.arange(12, dtype=np.float64).reshape(3, 4) + 100.25
    z[1, 2] = -9999.0
    transform = Affine(0.5, 0.0, 10.0, 0.0, -0.5, 21.5)
    out = tmp_path / "small.tif"
    write_geotiff(out, z, transform=transform, crs=None)
    got, profile, crs, t, blocks = _read(out)
    assert crs is None and t == transform
    assert out.stat().st_size < 4096                                # one deflated tile
    np.testing.assert_array_equal(got, z.astype(np.float32))
    with rasterio.open(out) as src:
        assert not src.read_masks(1)[1, 2] and src.read_masks(1).sum() == 11 * 255
    write_geotiff(out, z + 1.0, transform=transform, crs=None)      # replaces the old file
    np.testing.assert_array_equal(_read(out)[0][0], (z[0] + 1.0).astype(np.float32))


def test_missing_folder_is_input_error(tmp_path):
    z = np.zeros((2, 2))
    with pytest.raises(InputError, match="does not exist"):
        write_geotiff(tmp_path / "nope" / "dtm.tif", z, transform=Affine.identity(), crs=None)


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    out = tmp_path / "dtm.tif"
    out.write_bytes(b"old")

    def fail(*args, **kwargs):
        raise RuntimeError("disk full")

    monkeypatch.setattr(rasterio, "open", fail)
    with pytest.raises(RuntimeError, match="disk full"):
        write_geotiff(out, np.zeros((2, 2)), transform=Affine(1, 0, 0, 0, -1, 2), crs=None)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["dtm.tif"]


def test_hillshade_png(samp12_dtm, tmp_path):
    out = tmp_path / "hs.png"
    samp12_dtm.to_png(out)
    rgba = matplotlib.image.imread(out)
    assert rgba.shape == (*samp12_dtm.shape, 4)
    valid = samp12_dtm.valid
    np.testing.assert_array_equal(rgba[..., 3] > 0, valid)          # nodata is transparent
    shade = samp12_dtm.hillshade()
    np.testing.assert_allclose(rgba[valid, 0], shade[valid], atol=2.5 / 255)     # 256-entry LUT, 8-bit PNG


def test_a_vrt_mosaic_reads_as_the_geotiff_mosaic_and_moves_with_its_folder(tmp_path):
    import shutil

    from gfjax.dtm import mosaic

    rng = np.random.default_rng(4)
    folder = tmp_path / "survey"
    (folder / "dtm").mkdir(parents=True)
    crs = rasterio.crs.CRS.from_epsg(32632)
    paths = []
    for k, (x0, y0, h, w) in enumerate([(500_000.0, 5_000_040.0, 30, 40), (500_038.0, 5_000_050.0, 25, 30),
                                        (500_010.0, 5_000_010.0, 20, 20)]):
        z = rng.uniform(100, 110, (h, w))
        z[rng.random((h, w)) < 0.1] = -9999.0                       # holes: the next file shows through
        paths.append(folder / "dtm" / f"t{k}.tif")
        write_geotiff(paths[-1], z, transform=Affine(1.0, 0.0, x0, 0.0, -1.0, y0), crs=crs)
    assert mosaic(paths, folder / "m.tif") == mosaic(paths, folder / "m.vrt")
    shutil.move(folder, tmp_path / "moved")
    with rasterio.open(tmp_path / "moved" / "m.tif") as tif, rasterio.open(tmp_path / "moved" / "m.vrt") as vrt:
        assert vrt.driver == "VRT" and vrt.crs == tif.crs and vrt.transform == tif.transform
        assert vrt.nodata == tif.nodata
        np.testing.assert_array_equal(vrt.read(1), tif.read(1))
