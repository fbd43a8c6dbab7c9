"""GeoTIFF output of a DTM (rasterio), and the CRS of a cloud in rasterio's terms.

The raster is written in the cloud's own CRS and units: coordinates are never converted, so a
feet file gives a GeoTIFF in feet. Writes are atomic: a temporary file in the target folder,
renamed over the target only when complete, so a failed run never leaves a partial file.
"""
from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import warnings

import numpy as np
import rasterio
import rasterio.crs
import rasterio.errors
from rasterio.transform import Affine

from gfjax.errors import InputError
from gfjax.io import crs as crs_lib
from gfjax.io.atomic import atomic_output

NODATA = -9999.0
TILE_PX = 256                  # GeoTIFF block size (COG tiles)


def cloud_rasterio_crs(cloud) -> rasterio.crs.CRS | None:
    """The CRS of `cloud` (`cloud.crs`, read by `gfjax.io`) as a `rasterio.crs.CRS`, or None.

    Raises:
      InputError: GDAL does not accept the CRS (names the file).
    """
    try:
        return crs_lib.rasterio_crs(cloud)
    except rasterio.errors.CRSError as err:
        raise InputError(f"{cloud.name}: GDAL does not accept the file's CRS ({err})") from None


def write_geotiff(path, z: np.ndarray, *, transform: Affine, crs: rasterio.crs.CRS | None,
                  nodata: float = NODATA) -> None:
    """Write one float32 band as a cloud-optimised GeoTIFF (GDAL's COG driver: 256 x 256
    tiles, overviews, deflate with the floating-point predictor), atomically.

    Args:
      path: target `.tif`; its folder must exist.
      z: elevations `(h, w)`, row 0 north; `nodata` where no value.
      transform: pixel -> CRS affine transform (north-up: `e < 0`).
      crs: rasterio CRS, or None (the file then has none).
      nodata: stored as the band's nodata value.

    A COG opens at any zoom without reading the whole file, in QGIS or over HTTP, and is an
    ordinary GeoTIFF to every other reader.
    """
    z = np.asarray(z)
    if z.ndim != 2 or z.size == 0:
        raise ValueError(f"z must be a non-empty (h, w) raster, got shape {z.shape}")
    h, w = z.shape
    profile = dict(driver="COG", height=h, width=w, count=1, dtype="float32", crs=crs,
                   transform=transform, nodata=nodata, compress="deflate", predictor="YES",
                   blocksize=TILE_PX, BIGTIFF="IF_SAFER")
    with atomic_output(path, force=True) as tmp, _gdal_messages():
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(z.astype(np.float32), 1)


@contextlib.contextmanager
def _gdal_messages():
    """What GDAL and libtiff print on the process's stderr during a write ("_tiffWriteProc:
    No space left on device": C code, past Python) is held back: a write that fails says its
    first line in the error, instead of rasterio's "See previous exception for details"; a
    write that succeeds passes it on."""
    sys.stderr.flush()
    saved = os.dup(2)
    held = tempfile.TemporaryFile()
    os.dup2(held.fileno(), 2)
    from rasterio._err import CPLE_BaseError  # GDAL's own errors (e.g. building the overviews)

    failed = False
    try:
        yield
    except (OSError, rasterio.errors.RasterioError, CPLE_BaseError) as err:
        failed = True
        os.dup2(saved, 2)
        held.seek(0)
        said = [line.strip() for line in held.read().decode(errors="replace").splitlines() if line.strip()]
        raise OSError(said[0] if said else str(err)) from None
    finally:
        if not failed:
            os.dup2(saved, 2)
            held.seek(0)
            text = held.read()
            if text:
                os.write(2, text)
        os.close(saved)
        held.close()


__all__ = ["NODATA", "cloud_rasterio_crs", "write_geotiff", "mosaic", "write_vrt"]


def mosaic(paths, target) -> tuple[int, int]:
    """Join DTM GeoTIFFs that lie on one lattice (`gfjax.dtm.build` snaps every cell edge to
    whole multiples of the cell) into one GeoTIFF, with `rasterio.merge.merge`; where two
    overlap, the first file in `paths` that has a value wins (a survey's DTMs agree on their
    shared border cells). Written atomically, like `write_geotiff`. A `target` ending in
    `.vrt` is a GDAL virtual mosaic instead (`write_vrt`): the files stay where they are and
    nothing is copied, so it costs no memory whatever the survey's size.

    Args:
      paths: the DTM files (one CRS and cell size).
      target: the mosaic `.tif` (or `.vrt`).

    Returns: the mosaic's `(h, w)`.

    Raises:
      InputError: files whose CRS or cell size differ, or a mosaic over the memory budget.
    """
    import rasterio.merge

    from gfjax import limits

    if str(target).lower().endswith(".vrt"):
        return write_vrt(paths, target)
    sources = [rasterio.open(p) for p in paths]
    try:
        first = sources[0]
        _check_joinable(sources)
        left = min(s.bounds.left for s in sources)
        right = max(s.bounds.right for s in sources)
        bottom = min(s.bounds.bottom for s in sources)
        top = max(s.bounds.top for s in sources)
        w, h = round((right - left) / first.res[0]), round((top - bottom) / first.res[1])
        try:
            limits.check_memory([limits.Estimate(f"a DTM mosaic of {h:,} x {w:,} cells", 8.0 * h * w)])
        except ValueError as err:
            raise InputError(f"{target}: {err}; use a larger --cell, or a virtual mosaic (a .vrt "
                             "target), which copies nothing") from None
        with warnings.catch_warnings():   # rasterio.merge still composes transforms with `*`
            warnings.filterwarnings("ignore", "Use `@` matmul", PendingDeprecationWarning)
            z, transform = rasterio.merge.merge(sources, nodata=NODATA)
        write_geotiff(target, z[0], transform=transform, crs=first.crs)
        return z.shape[1], z.shape[2]
    finally:
        for src in sources:
            src.close()


def _check_joinable(sources) -> None:
    first = sources[0]
    for src in sources[1:]:
        if src.crs != first.crs or src.res != first.res:
            raise InputError(f"{src.name}: CRS or cell size differ from {first.name}; cannot join them "
                             "into one mosaic")


def write_vrt(paths, target) -> tuple[int, int]:
    """A GDAL virtual raster (VRT, GDAL's XML format) that mosaics DTM GeoTIFFs on one lattice
    without copying them: each file a source placed at its cells, its nodata transparent, the
    first file of `paths` on top where two overlap (as `mosaic`). Sources are named relative
    to the VRT's folder, so the folder can move as a whole. GDAL (`gdalinfo`, QGIS, rasterio)
    opens it as one raster. Written atomically.

    No library at hand writes one (GDAL's `BuildVRT` is not reachable through rasterio), and
    the format is GDAL's documented XML (gdal.org, "VRT -- GDAL Virtual Format").

    Returns: the mosaic's `(h, w)`.

    Raises:
      InputError: files whose CRS or cell size differ.
    """
    import xml.etree.ElementTree as ET

    target = os.path.abspath(target)
    sources = [rasterio.open(p) for p in paths]
    try:
        _check_joinable(sources)
        first = sources[0]
        cell_x, cell_y = first.res
        left = min(s.bounds.left for s in sources)
        top = max(s.bounds.top for s in sources)
        right = max(s.bounds.right for s in sources)
        bottom = min(s.bounds.bottom for s in sources)
        w, h = round((right - left) / cell_x), round((top - bottom) / cell_y)
        root = ET.Element("VRTDataset", rasterXSize=str(w), rasterYSize=str(h))
        if first.crs is not None:
            ET.SubElement(root, "SRS", dataAxisToSRSAxisMapping="1,2").text = first.crs.to_wkt()
        ET.SubElement(root, "GeoTransform").text = f"{left!r}, {cell_x!r}, 0.0, {top!r}, 0.0, {-cell_y!r}"
        band = ET.SubElement(root, "VRTRasterBand", dataType="Float32", band="1")
        ET.SubElement(band, "NoDataValue").text = repr(NODATA)
        for src in reversed(sources):                     # drawn in order: the first file last, on top
            item = ET.SubElement(band, "ComplexSource")
            name = os.path.relpath(os.path.abspath(src.name), os.path.dirname(target))
            ET.SubElement(item, "SourceFilename", relativeToVRT="1").text = name
            ET.SubElement(item, "SourceBand").text = "1"
            size = dict(xSize=str(src.width), ySize=str(src.height))
            ET.SubElement(item, "SrcRect", xOff="0", yOff="0", **size)
            ET.SubElement(item, "DstRect", xOff=str(round((src.bounds.left - left) / cell_x)),
                          yOff=str(round((top - src.bounds.top) / cell_y)), **size)
            ET.SubElement(item, "NODATA").text = repr(NODATA)
        ET.indent(root)
        text = ET.tostring(root, encoding="unicode") + "\n"
    finally:
        for src in sources:
            src.close()
    with atomic_output(target, force=True) as tmp, open(tmp, "w", encoding="utf-8") as out:
        out.write(text)
    return h, w
