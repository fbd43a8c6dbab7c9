"""`Cloud`: a LAS/LAZ point record kept whole on the host, plus the views the filters need.

The full `laspy.LasData` is kept untouched (header, VLRs/EVLRs, every point dimension, extra
bytes) so that writing it back changes nothing but the classification. Filters work on
`xyz_m` (float64 metres, converted from the file's horizontal/vertical units) or on
`local_xyz_m()` (float32 metres relative to an origin, what JAX code receives), and on
`frame` (a `Frame`: the box its tiles and grids are laid on, a survey's so adjacent files agree).
"""
from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple, Protocol, runtime_checkable

import laspy
import numpy as np

from gfjax.io import asprs, columns

if TYPE_CHECKING:
    import pyproj


class Frame(NamedTuple):
    """The box a tiling is laid on: its lattice starts at `origin_m` and windows stop at `upper_m`.

    A cloud carries it (`Cloud.frame`, `Points.frame`; None: the cloud's own box), so it lives
    with the cloud; `gfjax.tiling.tiles.split` lays its tiles on it, and the methods that do not
    tile snap their grids to it (`snap`).

    Attributes:
      origin_m: float64 `(3,)` minimum x, y, z of the points filtered [m].
      upper_m: float64 `(2,)` maximum x, y [m].
      cores: the keys `(col, row)` of the only tiles `gfjax.tiling.tiles.split` makes (None: every tile holding a
        point): a survey filters each tile of its lattice once, from a window of its points
        that also holds parts of the neighbouring tiles (`gfjax.survey.lattice`).
    """

    origin_m: np.ndarray
    upper_m: np.ndarray
    cores: frozenset[tuple[int, int]] | None = None

    @classmethod
    def of(cls, xyz_m: np.ndarray) -> Frame:
        """The frame of points `(n, 3)` (n >= 1): their bounding box."""
        xyz_m = np.asarray(xyz_m, np.float64)
        return cls(columns.lows(xyz_m), columns.highs(xyz_m[:, :2]))

    def union(self, other: Frame) -> Frame:
        return Frame(np.minimum(self.origin_m, other.origin_m), np.maximum(self.upper_m, other.upper_m))

    def only(self, cores) -> Frame:
        """This frame, with `split` making only the tiles of the keys `cores` `(col, row)`."""
        return self._replace(cores=frozenset((int(c), int(r)) for c, r in cores))

    def snap(self, corner_m: np.ndarray, cell_m: float) -> np.ndarray:
        """The corner of the cell of this frame's lattice (cubes of `cell_m` from `origin_m`)
        that holds `corner_m` (float64 `(3,)` [m]): a window of a survey anchored there grids
        its points into the cells the whole survey in one file would use."""
        origin = np.asarray(self.origin_m, np.float64)
        return origin + np.floor((np.asarray(corner_m, np.float64) - origin) / cell_m) * cell_m


@runtime_checkable
class CloudView(Protocol):
    """What a filter reads from a cloud: a `Cloud`, or a survey's `Points` (a file and the
    halo of its neighbours' points, `gfjax.survey`)."""

    name: str
    frame: Frame | None

    @property
    def xyz_m(self) -> np.ndarray: ...

    @property
    def n_points(self) -> int: ...

    def filter_mask(self, returns: str = "all") -> np.ndarray: ...


def use_mask(ignored: np.ndarray, return_number: np.ndarray | None, number_of_returns: np.ndarray | None,
             returns: str = "all") -> np.ndarray:
    """Points a filter uses, bool `(n,)`: not ignored, and last returns only when `returns == "last"`
    (the return numbers are read only then)."""
    use = ~np.asarray(ignored, bool)
    if returns == "last":
        use &= np.asarray(return_number) >= np.asarray(number_of_returns)
    elif returns != "all":
        raise ValueError(f"returns must be 'all' or 'last', got {returns!r}")
    return use


@dataclasses.dataclass(frozen=True, eq=False)
class Points:
    """The views a filter reads from a cloud (`Cloud.xyz_m`, `filter_mask`, ...), as plain arrays:
    a survey's window (a file and its neighbours' points, `gfjax.survey`), or some points of a
    cloud filtered as a cloud of their own (`gfjax.tiling.groups.filter_groups`).

    Attributes:
      xyz_m: float64 `(n, 3)` [m].
      classification, return_number, number_of_returns: uint8 `(n,)`.
      ignored: bool `(n,)` noise or withheld.
      name: for messages.
      frame: the tiling frame (`Frame`), or None.
    """

    xyz_m: np.ndarray
    classification: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    ignored: np.ndarray
    name: str = "<memory>"
    frame: Frame | None = None

    @property
    def n_points(self) -> int:
        return int(self.xyz_m.shape[0])

    @classmethod
    def from_records(cls, records: np.ndarray | Sequence[np.ndarray], name: str, frame: Frame | None = None) -> Points:
        """The points of a catalog's `STORE` records `(n,)` (`gfjax.survey.catalog`): views of
        its fields; or of a non-empty sequence of such arrays one after another: each field one
        contiguous array (a record's fields are 28 bytes apart, and every pass of a filter over a
        strided column costs more: a survey's tile window, `gfjax.survey.lattice`)."""
        if isinstance(records, np.ndarray):

            def field(name: str) -> np.ndarray:
                return np.asarray(records[name])
        else:
            parts = list(records)

            def field(name: str) -> np.ndarray:
                return np.concatenate([part[name] for part in parts])

        return cls(xyz_m=field("xyz_m"), classification=field("classification"), return_number=field("return_number"),
                   number_of_returns=field("number_of_returns"), ignored=field("ignored"), name=name, frame=frame)

    @classmethod
    def of_xyz(cls, xyz_m: np.ndarray, name: str = "<memory>") -> Points:
        """Points `(n, 3)` [m], every one used (single returns, none ignored), with no frame."""
        n = len(xyz_m)
        ones = np.ones(n, np.uint8)
        return cls(xyz_m=np.asarray(xyz_m, np.float64), classification=np.ones(n, np.uint8), return_number=ones,
                   number_of_returns=ones, ignored=np.zeros(n, bool), name=name)

    @classmethod
    def of(cls, cloud: Cloud | Points, keep: np.ndarray | None = None) -> Points:
        """The points `keep` (int rows, or bool `(n,)`; None: every point) of a `Cloud` or
        `Points` as plain arrays, with its name and frame (a random subset of a file stands for
        a sparser survey of it: `gfjax.sparsegf.train.thinned`)."""
        def rows(values: np.ndarray) -> np.ndarray:
            return np.asarray(values if keep is None else values[keep])

        return cls(xyz_m=rows(cloud.xyz_m), classification=rows(cloud.classification),
                   return_number=rows(cloud.return_number), number_of_returns=rows(cloud.number_of_returns),
                   ignored=rows(cloud.ignored), name=cloud.name, frame=cloud.frame)

    def filter_mask(self, returns: str = "all") -> np.ndarray:
        return use_mask(self.ignored, self.return_number, self.number_of_returns, returns)


@dataclasses.dataclass(frozen=True, eq=False)
class Cloud:
    """A point cloud read from a LAS/LAZ file (or built in memory).

    Attributes:
      las: the complete laspy record; never modified in place.
      path: the file it came from, or None.
      horizontal_unit_m: metres per horizontal coordinate unit (1.0, 0.3048, 1200/3937).
      vertical_unit_m: metres per vertical coordinate unit.
      crs: the file's coordinate reference system (`pyproj.CRS`), or None when it states none.
      units_source: where the unit factors came from ("CRS", "--units ft", "no CRS in file:
        metres assumed", ...), for `gfjax info` and logs.
      frame: the box the tiled filters lay their lattice on (`Frame`; a
        survey's, so adjacent files agree), or None for the cloud's own.
      classes: which classes filters ignore and which keep their class (`asprs.ClassRules`;
        default: noise and withheld points ignored, every other class relabelled); set with
        `with_classes`.
    """

    las: laspy.LasData
    path: Path | None = None
    horizontal_unit_m: float = 1.0
    vertical_unit_m: float = 1.0
    crs: pyproj.CRS | None = None
    units_source: str = "in memory: metres"
    frame: Frame | None = None
    classes: asprs.ClassRules = asprs.DEFAULT_RULES

    @property
    def n_points(self) -> int:
        return len(self.las.points)

    def _copied_las(self, header: laspy.LasHeader) -> laspy.LasData:
        """A new record of this cloud's points (copied) under `header`, with its EVLRs."""
        las = laspy.LasData(header=header, points=self.las.points.copy())
        if getattr(self.las, "evlrs", None) is not None:
            las.evlrs = self.las.evlrs
        return las

    def with_classes(self, *, ignore=(), keep=()) -> Cloud:
        """This cloud with the classes `ignore` (never used, never relabelled; noise always)
        and `keep` (used as context, never relabelled) of `asprs.ClassRules`."""
        return dataclasses.replace(self, classes=asprs.ClassRules(frozenset(ignore), frozenset(keep)))

    @property
    def name(self) -> str:
        return str(self.path) if self.path is not None else "<memory>"

    @property
    def xyz(self) -> np.ndarray:
        """Scaled coordinates in file units, float64, shape `(n, 3)`."""
        return np.stack([np.asarray(self.las.x, dtype=np.float64),
                         np.asarray(self.las.y, dtype=np.float64),
                         np.asarray(self.las.z, dtype=np.float64)], axis=1)

    @functools.cached_property
    def xyz_m(self) -> np.ndarray:
        """Coordinates in metres, float64, shape `(n, 3)` (file units times the unit factors).

        Made once per cloud and kept (read-only): a filter run reads it several times (the
        terrain, the method, the spike guard), and each scaling of laspy's integers into
        metres took about 10 ms on 823,945 points. A copy is the caller's to change (`.copy()`);
        a cloud made by `with_ground`, `with_z`, ... makes its own.
        """
        xyz = self.xyz
        if self.horizontal_unit_m != 1.0:
            xyz[:, :2] *= self.horizontal_unit_m
        if self.vertical_unit_m != 1.0:
            xyz[:, 2] *= self.vertical_unit_m
        xyz.flags.writeable = False
        return xyz

    def local_xyz_m(self, origin_m: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Float32 metres relative to `origin_m` (default: the minimum corner), and the origin.

        Returns:
          `(local, origin)`: local float32 `(n, 3)` and origin float64 `(3,)`, metres.
        """
        xyz = self.xyz_m
        if origin_m is None:
            origin_m = columns.lows(xyz) if len(xyz) else np.zeros(3)
        return (xyz - origin_m).astype(np.float32), np.asarray(origin_m, dtype=np.float64)

    @property
    def classification(self) -> np.ndarray:
        """ASPRS class per point, uint8 `(n,)`."""
        return np.asarray(self.las.classification, dtype=np.uint8)

    @property
    def return_number(self) -> np.ndarray:
        return np.asarray(self.las.return_number, dtype=np.uint8)

    @property
    def number_of_returns(self) -> np.ndarray:
        return np.asarray(self.las.number_of_returns, dtype=np.uint8)

    @property
    def ignored(self) -> np.ndarray:
        """Points every filter ignores (`classes.ignore`, by default noise classes 7 and 18, and the
        withheld flag), bool `(n,)`."""
        return self.classes.ignored(self.las)

    def filter_mask(self, returns: str = "all") -> np.ndarray:
        """Points a filter uses: not ignored, and last returns only when `returns == "last"`."""
        if returns == "all":        # no return numbers read: bit fields laspy unpacks at 2 ms a million
            return use_mask(self.ignored, None, None, returns)
        return use_mask(self.ignored, self.return_number, self.number_of_returns, returns)

    def with_ground(self, ground: np.ndarray, *, reset_nonground: bool = False,
                    used: np.ndarray | None = None) -> Cloud:
        """A copy whose classification says ground (2) / non-ground, per SPEC section 1.

        Ground points get class 2. Non-ground points that were class 2 become 1; other
        non-ground points keep their class unless `reset_nonground` (then all become 1).
        Points outside `used` (default: not ignored) and points of the classes `classes`
        keeps keep their class whatever `ground` says.
        """
        ground = np.asarray(ground, dtype=bool)
        if ground.shape != (self.n_points,):
            raise ValueError(f"{self.name}: ground must have shape ({self.n_points},), got {ground.shape}")
        if used is None:
            used = ~self.ignored
        new = asprs.relabel(self.classification, ground, used, reset_nonground=reset_nonground, rules=self.classes)
        las = self._copied_las(self.las.header)
        las.classification = new
        return dataclasses.replace(self, las=las)

    def with_z(self, z: np.ndarray) -> Cloud:
        """A copy whose z are `z` (float `(n,)`, in the file's vertical unit; e.g. heights above
        ground), stored at the file's z scale with a z offset of 0; everything else as read."""
        z = np.asarray(z, np.float64)
        if z.shape != (self.n_points,):
            raise ValueError(f"{self.name}: z must have shape ({self.n_points},), got {z.shape}")
        header = copy.deepcopy(self.las.header)
        header.offsets = np.array([header.offsets[0], header.offsets[1], 0.0])
        las = self._copied_las(header)
        las.x, las.y = np.asarray(self.las.x), np.asarray(self.las.y)      # as stored: the same integers
        las.z = z
        return dataclasses.replace(self, las=las)

    def with_extra_dim(self, name: str, values: np.ndarray, *, description: str = "") -> Cloud:
        """A copy with an extra-bytes dimension `name` set to `values` (shape `(n,)`).

        The dtype of `values` becomes the dimension's type (e.g. uint32 `instance_id`). An
        existing dimension of that name is overwritten in place of adding a second one. The
        header is copied, so `self` is unchanged.
        """
        values = np.asarray(values)
        if values.shape != (self.n_points,):
            raise ValueError(f"{self.name}: {name} must have shape ({self.n_points},), got {values.shape}")
        header = copy.deepcopy(self.las.header)
        las = self._copied_las(header)
        if name not in set(las.point_format.dimension_names):
            las.add_extra_dim(laspy.ExtraBytesParams(name=name, type=values.dtype, description=description))
        las[name] = values
        return dataclasses.replace(self, las=las)

    @classmethod
    def from_xyz(cls, xyz: np.ndarray, *, classification: np.ndarray | None = None,
                 scale: float = 0.001, point_format: int = 6, version: str = "1.4") -> Cloud:
        """An in-memory cloud from float64 metres `(n, 3)` (tests, synthetic scenes)."""
        xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
        header = laspy.LasHeader(point_format=point_format, version=version)
        header.scales = np.array([scale] * 3)
        header.offsets = np.floor(xyz.min(axis=0)) if len(xyz) else np.zeros(3)
        las = laspy.LasData(header)
        las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        if classification is not None:
            las.classification = np.asarray(classification, dtype=np.uint8)
        return cls(las=las)
