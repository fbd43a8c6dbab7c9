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
    failed = False
    try:
        yield
    except OSError as err:
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


__all__ = ["NODATA", "cloud_rasterio_crs", "write_geotiff", "mosaic"]


def mosaic(paths, target) -> tuple[int, int]:
    """Join DTM GeoTIFFs that lie on one lattice (`gfjax.dtm.build` snaps every cell edge to
    whole multiples of the cell) into one GeoTIFF, with `rasterio.merge.merge`; where two
    overlap, the first file in `paths` that has a value wins (a survey's DTMs agree on their
    shared border cells). Written atomically, like `write_geotiff`.

    Args:
      paths: the DTM files (one CRS and cell size).
      target: the mosaic `.tif`.

    Returns: the mosaic's `(h, w)`.

    Raises:
      InputError: files whose CRS or cell size differ, or a mosaic over the memory budget.
    """
    import rasterio.merge

    from gfjax import limits

    sources = [rasterio.open(p) for p in paths]
    try:
        first = sources[0]
        for src in sources[1:]:
            if src.crs != first.crs or src.res != first.res:
                raise InputError(f"{src.name}: CRS or cell size differ from {first.name}; cannot join them "
                                 "into one mosaic")
        left = min(s.bounds.left for s in sources)
        right = max(s.bounds.right for s in sources)
        bottom = min(s.bounds.bottom for s in sources)
        top = max(s.bounds.top for s in sources)
        w, h = round((right - left) / first.res[0]), round((top - bottom) / first.res[1])
        try:
            limits.check_memory([limits.Estimate(f"a DTM mosaic of {h:,} x {w:,} cells", 8.0 * h * w)])
        except ValueError as err:
            raise InputError(f"{target}: {err}; use a larger --cell, or join the DTMs with GDAL "
                             "(gdalbuildvrt)") from None
        with warnings.catch_warnings():   # rasterio.merge still composes transforms with `*`
            warnings.filterwarnings("ignore", "Use `@` matmul", PendingDeprecationWarning)
            z, transform = rasterio.merge.merge(sources, nodata=NODATA)
        write_geotiff(target, z[0], transform=transform, crs=first.crs)
        return z.shape[1], z.shape[2]
    finally:
        for src in sources:
            src.close()
