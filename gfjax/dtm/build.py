"""Build a DTM raster from the ground points of a cloud: cell means, TIN fill, nodata.

Steps (SPEC section 1 "dtm.build"):
1. A grid of square cells of `cell_m` metres, converted to the file's horizontal unit (feet
   data get a 3.2808 ft cell for 1 m), with its origin snapped to whole multiples of the cell
   so DTMs of neighbouring tiles line up. It covers the x-y extent of the cloud's points
   (noise and withheld points, which filters ignore, excepted).
   Row 0 is the northern edge; a cell spans `[x0, x0 + cell) x [y0, y0 + cell)`, so a point
   on a boundary belongs to the cell east / north of it (`row = h - 1 - floor(y / cell)`,
   docs/ARCHITECTURE.md).
2. Cells holding ground points get the mean ground elevation (file's vertical unit).
3. Empty cells are filled by linear interpolation in a TIN (scipy Delaunay) whose vertices
   are the ground **centroids of the occupied cells** (mean x, mean y, mean z of the ground
   points in the cell), and only inside triangles whose longest edge is at most `max_edge_m`.
   Why centroids rather than every ground point or the cell centres:
   - the mean z of points on a plane equals the plane at their mean x, y, so the TIN of
     centroids reproduces a planar terrain exactly, like a TIN of all points, while the cell
     centres carry the cell mean at a position it does not belong to (an error of slope
     times up to half a cell);
   - the filled cells join the measured cells without a step: the TIN passes through the
     same means the occupied cells hold;
   - the triangulation costs scale with occupied cells, not points (forest tiles hold 12-15
     points per m^2);
   - vertices are not on a lattice, so Delaunay is rarely degenerate.
4. Other cells get `nodata` (-9999).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import scipy.spatial
from rasterio.transform import Affine

from gfjax import limits
from gfjax.dtm.geotiff import NODATA, cloud_rasterio_crs, write_geotiff
from gfjax.dtm.hillshade import hillshade, write_png
from gfjax.errors import InputError
from gfjax.io.cloud import Cloud

# The valid ranges of the DTM options (`gfjax filter --cell`, `gfjax dtm --cell --max-edge`).
RANGES: dict[str, limits.Range] = {
    "cell_m": limits.Range(0, 1000, low_open=True, unit="m"),
    "max_edge_m": limits.Range(0, None, unit="m", inf_ok=True),
}
DEFAULTS = {"cell_m": 1.0, "max_edge_m": 100.0}
# z and the TIN fill (float64), counts (int64), masks and the float32 copy written [bytes per cell].
_BYTES_PER_CELL = 48


@dataclasses.dataclass(frozen=True, eq=False)
class DTM:
    """A terrain raster in the cloud's CRS and units; row 0 is the northern edge.

    Attributes:
      z: elevations, float64 `(h, w)`, the file's vertical unit; `nodata` where no value.
      count: ground points per cell, int32 `(h, w)`; 0 where `z` is interpolated or nodata.
      origin: `(x, y)` of the north-west corner, file units, whole multiples of `cell`.
      cell: cell size in the file's horizontal unit.
      crs: `rasterio.crs.CRS` of the cloud, or None.
      horizontal_unit_m, vertical_unit_m: metres per file unit (for slopes and hillshade).
      nodata: the value of cells without an elevation.
    """

    z: np.ndarray
    count: np.ndarray
    origin: tuple[float, float]
    cell: float
    crs: object = None
    horizontal_unit_m: float = 1.0
    vertical_unit_m: float = 1.0
    nodata: float = NODATA

    @property
    def shape(self) -> tuple[int, int]:
        return self.z.shape

    @property
    def valid(self) -> np.ndarray:
        """Cells with an elevation, bool `(h, w)`."""
        return self.z != self.nodata

    @property
    def transform(self) -> Affine:
        """Pixel (col, row) -> (x, y) of the cell's north-west corner (rasterio convention)."""
        return Affine(self.cell, 0.0, self.origin[0], 0.0, -self.cell, self.origin[1])

    def to_geotiff(self, path) -> None:
        """Write a float32 GeoTIFF (deflate, tiled when large) atomically; see `write_geotiff`."""
        write_geotiff(path, self.z, transform=self.transform, crs=self.crs, nodata=self.nodata)

    def hillshade(self, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
        """Shaded relief in [0, 1], float64 `(h, w)`, NaN on nodata cells; see `hillshade`."""
        return hillshade(self.z, self.valid, cell=self.cell,
                         z_factor=self.vertical_unit_m / self.horizontal_unit_m,
                         azimuth_deg=azimuth_deg, altitude_deg=altitude_deg)

    def to_png(self, path, *, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> None:
        """Write the hillshade as a grey PNG (nodata transparent), atomically."""
        write_png(path, self.hillshade(azimuth_deg, altitude_deg))


def checked_ground(cloud: Cloud, ground, what: str) -> np.ndarray:
    """`ground` as a bool array over `cloud`'s points, with at least one True; else
    `InputError` naming the file and `what` cannot be built ("a DTM")."""
    ground = np.asarray(ground)
    if ground.dtype != np.bool_ or ground.shape != (cloud.n_points,):
        raise InputError(f"{cloud.name}: ground must be a bool array of shape ({cloud.n_points},), "
                         f"got {ground.dtype} {ground.shape}")
    if not ground.any():
        raise InputError(f"{cloud.name}: no ground points (class 2 or filter result), cannot build {what}")
    return ground


def check_grid(name: str, h: int, w: int, cell_m: float, what: str) -> None:
    """`InputError` naming the file when a raster of `h` x `w` cells (`what`, "a DTM") passes the
    memory budget (`_BYTES_PER_CELL` a cell)."""
    try:
        limits.check_memory([limits.Estimate(f"{what} of {h:,} x {w:,} cells of {cell_m:g} m (extent / --cell)",
                                             float(h) * float(w) * _BYTES_PER_CELL)])
    except ValueError as err:
        raise InputError(f"{name}: {err}; use a larger --cell or split the file") from None


def check_options(name: str, *, cell_m, max_edge_m=100.0) -> tuple[float, float]:
    """`cell_m` and `max_edge_m` as floats, checked against `RANGES`.

    Raises InputError `"<name>: cell_m (--cell) must be ..."`, or without `name` (options
    checked before any file is read) `"--cell: cell_m must be ..."`.
    """
    checked = []
    for key, option, value in (("cell_m", "--cell", cell_m), ("max_edge_m", "--max-edge", max_edge_m)):
        try:
            limits.check_value(f"{key} ({option})" if name else key, value, RANGES[key])
        except ValueError as err:
            raise InputError(f"{name or option}: {err}") from None
        checked.append(float(value))
    return checked[0], checked[1]


def memory_estimate(extent_m: tuple[float, float], cell_m: float) -> limits.Estimate:
    """The DTM raster over an x, y extent [m] at `cell_m` [m] (`gfjax.limits.check_memory`)."""
    w, h = (limits.raster_side(e, cell_m) for e in extent_m)
    return limits.Estimate(f"a DTM of {h:,} x {w:,} cells of {cell_m:g} m (extent / --cell)",
                           float(h) * float(w) * _BYTES_PER_CELL)


def snapped_grid(xy: np.ndarray, cell: float) -> tuple[int, int, int, int]:
    """The grid of `cell`-sized cells, snapped to multiples of `cell`, that covers `xy`.

    Args:
      xy: float64 `(n, 2)`, n >= 1, file units.
      cell: cell size, file units.

    Returns:
      `(col0, row_top, h, w)`: the western edge is `col0 * cell`, the northern edge
      `row_top * cell` (both whole multiples of `cell`); shape `(h, w)`.
    """
    ix = np.floor(xy[:, 0] / cell)
    iy = np.floor(xy[:, 1] / cell)
    col0, col1 = int(ix.min()), int(ix.max())
    row0, row1 = int(iy.min()), int(iy.max())
    return col0, row1 + 1, row1 - row0 + 1, col1 - col0 + 1


def _rasterize_tin(vertices_px: np.ndarray, shape: tuple[int, int], max_edge_px: float,
                   *, chunk: int = 1 << 21) -> np.ndarray:
    """Linear TIN interpolation at every cell centre; NaN outside the TIN or in long triangles.

    Args:
      vertices_px: `(k, 3)` vertices: column and row coordinates in cells (cell `(r, c)` spans
        `[c, c + 1) x [r, r + 1)`, its centre is `(c + 0.5, r + 0.5)`), and z.
      shape: `(h, w)` of the raster.
      max_edge_px: triangles with a longer edge (cells) are not used.
      chunk: cells tested per batch (bounds memory).

    Returns:
      float64 `(h, w)`. Fewer than three vertices, or collinear ones (a one-row tile), give no
      triangle: all NaN.

    Each triangle is scanned over the cell centres of its bounding box with barycentric
    coordinates, in vectorised numpy: the cost is the summed bounding-box area, about twice
    the area of the triangulation, and needs no point location (scipy's `find_simplex`
    computes a LAPACK transform per simplex, slow under a multi-threaded BLAS).
    """
    h, w = shape
    out = np.full((h, w), np.nan)
    if vertices_px.shape[0] < 3:
        return out
    try:
        tri = scipy.spatial.Delaunay(vertices_px[:, :2])
    except scipy.spatial.QhullError:
        return out                                   # collinear vertices: no area to fill
    p = vertices_px[tri.simplices]                   # (t, 3 corners, [col, row, z])
    longest = np.linalg.norm(p[:, :, :2] - np.roll(p[:, :, :2], 1, axis=1), axis=2).max(axis=1)
    p = p[longest <= max_edge_px]
    (x1, x2, x3), (y1, y2, y3) = p[:, :, 0].T, p[:, :, 1].T
    det = (y2 - y3) * (x1 - x3) + (x3 - x2) * (y1 - y3)     # twice the signed area
    p, det = p[det != 0.0], det[det != 0.0]
    (x1, x2, x3), (y1, y2, y3), zs = p[:, :, 0].T, p[:, :, 1].T, p[:, :, 2]
    # bounding box of the cell centres (c + 0.5, r + 0.5) that may lie in each triangle
    eps = 1e-9
    c0 = np.clip(np.ceil(p[:, :, 0].min(axis=1) - 0.5 - eps), 0, w).astype(np.int64)
    c1 = np.clip(np.floor(p[:, :, 0].max(axis=1) - 0.5 + eps), -1, w - 1).astype(np.int64)
    r0 = np.clip(np.ceil(p[:, :, 1].min(axis=1) - 0.5 - eps), 0, h).astype(np.int64)
    r1 = np.clip(np.floor(p[:, :, 1].max(axis=1) - 0.5 + eps), -1, h - 1).astype(np.int64)
    ncol = np.maximum(c1 - c0 + 1, 1)                 # >= 1 keeps % and // defined
    n_cells = np.maximum(c1 - c0 + 1, 0) * np.maximum(r1 - r0 + 1, 0)
    start = np.cumsum(n_cells) - n_cells              # offset of each triangle's cells
    first = 0
    while first < n_cells.shape[0]:                   # batches of about `chunk` cells
        last = max(int(np.searchsorted(start, start[first] + chunk, side="right")), first + 1)
        t = np.repeat(np.arange(first, last), n_cells[first:last])
        k = np.arange(t.shape[0]) + start[first] - start[t]     # cell number inside the box
        col, row = c0[t] + k % ncol[t], r0[t] + k // ncol[t]
        x, y = col + 0.5 - x3[t], row + 0.5 - y3[t]
        l1 = ((y2[t] - y3[t]) * x + (x3[t] - x2[t]) * y) / det[t]
        l2 = ((y3[t] - y1[t]) * x + (x1[t] - x3[t]) * y) / det[t]
        l3 = 1.0 - l1 - l2
        inside = (l1 >= -eps) & (l2 >= -eps) & (l3 >= -eps)
        zi = l1 * zs[t, 0] + l2 * zs[t, 1] + l3 * zs[t, 2]
        out[row[inside], col[inside]] = zi[inside]
        first = last
    return out


def build(cloud: Cloud, ground, *, cell_m: float = 1.0, max_edge_m: float = 100.0,
          context_xyz: np.ndarray | None = None) -> DTM:
    """A DTM from the ground points of `cloud`.

    Args:
      cloud: the point cloud; its coordinates are used in file units (never converted).
      ground: bool `(n,)`, True for the points that make the terrain (e.g. `Result.ground`
        or `cloud.classification == 2`).
      cell_m: cell size in metres; in the raster it is `cell_m / cloud.horizontal_unit_m`
        file units (1 m -> 3.2808 ft for international feet).
      max_edge_m: longest triangle edge, metres, through which empty cells are interpolated;
        cells in longer triangles, or outside the hull of the cell centroids, stay nodata.
      context_xyz: ground points around the cloud, float64 `(m, 3)` in its file units (a
        survey file's surroundings, `gfjax.survey.Runner`): they enter the cells and triangles
        at the cloud's borders as they would in one DTM of the whole survey, so adjacent
        files' DTMs agree on their shared cells. The grid covers the cloud's own points.

    Returns:
      `DTM` with `z` float64 `(h, w)` in the file's vertical unit, `nodata` = -9999 where no
      value; `count` int32 `(h, w)` ground points per cell (0 = interpolated or nodata).

    Raises:
      InputError: a bad option, a `ground` of the wrong shape, no ground points, or a grid
        too large for memory. The message names the file.
    """
    name = cloud.name
    cell_m, max_edge_m = check_options(name, cell_m=cell_m, max_edge_m=max_edge_m)
    ground = checked_ground(cloud, ground, "a DTM")
    unit_m = cloud.horizontal_unit_m
    cell = cell_m / unit_m
    max_edge = max_edge_m / unit_m
    xyz = cloud.xyz                                        # file units, float64
    covered = xyz[~cloud.ignored | ground, :2]
    own = snapped_grid(covered, cell)
    xyz_g = xyz[ground]
    if context_xyz is not None and len(context_xyz):       # computed over both, cut to the own grid
        xyz_g = np.concatenate([xyz_g, np.asarray(context_xyz, np.float64).reshape(-1, 3)])
        covered = np.concatenate([covered, xyz_g[:, :2]])
    col0, row_top, h, w = snapped_grid(covered, cell)
    check_grid(name, h, w, cell_m, "a DTM")
    origin = np.array([col0 * cell, row_top * cell, 0.0])  # north-west corner, file units
    col = np.floor(xyz_g[:, 0] / cell).astype(np.int64) - col0    # same floor as the grid
    row = (row_top - 1) - np.floor(xyz_g[:, 1] / cell).astype(np.int64)
    local = xyz_g - origin                                 # centroids in local coordinates
    flat = row * w + col
    count = np.bincount(flat, minlength=h * w)
    occupied = np.flatnonzero(count)
    sums = np.stack([np.bincount(flat, weights=local[:, k], minlength=h * w)[occupied]
                     for k in range(3)], axis=1)
    centroids = sums / count[occupied, None]               # (k, 3): mean x, y, z per cell

    z = np.full((h, w), NODATA, dtype=np.float64)
    count = count.reshape(h, w)
    vertices_px = np.stack([centroids[:, 0] / cell, -centroids[:, 1] / cell, centroids[:, 2]], axis=1)
    tin = _rasterize_tin(vertices_px, (h, w), max_edge / cell)
    fill = (count == 0) & ~np.isnan(tin)
    z[fill] = tin[fill]
    z.reshape(-1)[occupied] = centroids[:, 2]
    own_col0, own_row_top, own_h, own_w = own
    rows = slice(row_top - own_row_top, row_top - own_row_top + own_h)
    cols = slice(own_col0 - col0, own_col0 - col0 + own_w)
    z, count = z[rows, cols], count[rows, cols]
    origin = np.array([own_col0 * cell, own_row_top * cell])
    return DTM(z=z, count=count.astype(np.int32),
               origin=(float(origin[0]), float(origin[1])), cell=float(cell),
               crs=cloud_rasterio_crs(cloud), horizontal_unit_m=unit_m,
               vertical_unit_m=cloud.vertical_unit_m)
