"""Labelled samples cut into tiles, prepared once, in fixed-shape buckets for the tuning loop.

A `Problem` holds, for a list of labelled clouds, the parameter-free part of a method's
pipeline (`GradientTuner.prepare_tile`: SMRF's openings, PMF's openings; CSF: whole samples and
their point-to-cloth distances, `GradientTuner.prepare_samples`) per shape bucket of `gfjax.tiling.batches`, with the
reference labels padded alike. Which labelled points count (a training half, a fold) is an
array argument (`Problem.masks`), not part of the compiled shapes, so every protocol of a
run reuses the same preparation and the same compiled loss.
"""
from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from gfjax.errors import InputError
from gfjax.io.cloud import Cloud
from gfjax.tiling import batches as batches_lib
from gfjax.tiling import tiles as tiling_lib
from gfjax.tiling.checks import lattice_of
from gfjax.tune import tuners

__all__ = ["Sample", "Bucket", "Problem", "block_ids", "block_folds"]


class Sample(NamedTuple):
    """One labelled cloud; a `gfjax.io.cloud.CloudView` of its own coordinates (exactly those of
    the file it came from, so a method's stages see what its `filter` sees).

    Attributes:
      name: for reports.
      xyz_m: float64 `(n, 3)` [m].
      ref_ground: bool `(n,)` reference ground (class 2).
      use: bool `(n,)` points the filter sees (noise and withheld excluded).
      returns: the returns `use` keeps ("all" or "last").
    """

    name: str
    xyz_m: np.ndarray
    ref_ground: np.ndarray
    use: np.ndarray
    returns: str = "all"

    @property
    def n_points(self) -> int:
        return len(self.xyz_m)

    @property
    def frame(self) -> None:
        """No survey frame: a sample is a cloud of its own (a `CloudView` for a method's stages)."""
        return None

    def filter_mask(self, returns: str = "all") -> np.ndarray:
        """`use`: the points of the `returns` the sample was made with (`from_cloud`)."""
        if returns != self.returns:
            raise ValueError(f"{self.name}: a sample of {self.returns!r} returns, asked for {returns!r}")
        return self.use

    @classmethod
    def from_cloud(cls, cloud: Cloud, *, returns: str = "all") -> Sample:
        """Reference ground = ASPRS class 2 of the cloud (ISPRS: object = class 0)."""
        try:
            use = cloud.filter_mask(returns)
        except ValueError as err:
            raise InputError(f"{cloud.name}: {err}") from None
        ref = np.asarray(cloud.classification) == 2
        return cls(cloud.name, np.asarray(cloud.xyz_m, np.float64), ref, use, returns)


@dataclasses.dataclass(frozen=True, eq=False)
class Bucket:
    """Tiles of one shape bucket, prepared (`Prepared` fields carry a leading `b` axis)."""

    prep: tuple                 # the method's Prepared
    ref: jax.Array              # bool (b, cap) reference ground
    cloud: jax.Array            # int32 (b,) sample index of each tile
    core_index: np.ndarray      # int64 (b, cap) cloud point index of core points, -1 elsewhere
    shape: tuple[int, int]


def block_ids(xyz_m: np.ndarray, *, block_m: float) -> np.ndarray:
    """Square spatial block `0..n_blocks-1` of each point (int64 `(n,)`), blocks of side
    `block_m` [m] anchored at the points' minimum x and y; only occupied blocks are numbered."""
    if not block_m > 0:
        raise ValueError(f"block_m must be > 0, got {block_m}")
    xy = np.asarray(xyz_m)[:, :2]
    if len(xy) == 0:
        return np.zeros(0, np.int64)
    cells = np.floor((xy - xy.min(axis=0)) / block_m).astype(np.int64)
    _, block = np.unique(cells, axis=0, return_inverse=True)
    return block.reshape(-1).astype(np.int64)


def block_folds(xyz_m: np.ndarray, *, folds: int, block_m: float, seed: int = 0) -> np.ndarray:
    """Fold id `0..folds-1` per point from square spatial blocks of `block_m` (int `(n,)`).

    Blocks are shuffled (seeded) and dealt round-robin to the folds, so folds are balanced in
    blocks and every block lies wholly in one fold (k-fold by block).
    """
    if folds < 2:
        raise ValueError(f"folds must be >= 2, got {folds}")
    block = block_ids(xyz_m, block_m=block_m)
    if block.size == 0:
        return block
    order = np.random.default_rng(seed).permutation(block.max() + 1)
    fold_of_block = np.empty_like(order)
    fold_of_block[order] = np.arange(order.size) % folds
    return fold_of_block[block]


@functools.partial(jax.jit, static_argnames=("method", "config", "shape"))
def _prepare_batch(xyz, valid, hw, *, method: tuners.GradientTuner, config, shape):
    fn = functools.partial(method.prepare_tile, config=config, shape=shape)
    return jax.vmap(fn)(xyz, valid, hw)


class Problem:
    """Labelled samples prepared for tuning a method (SMRF: at windows up to `max_window_m`).

    Args:
      samples: labelled clouds.
      config: the method's static settings (SMRF's window is replaced by
        `max(max_window_m, config.window_m)`).
      max_window_m: SMRF: the largest window tried (openings are computed up to it);
        ignored by methods without a static grid (PMF).
      method: the method's `GradientTuner` (`gfjax.smrf.tuning.TUNER`, ...); None: the one
        whose `Config` `config` is (`gfjax.tune.tuners.of_config`).
      max_batch: tiles per vmapped batch.
      grid: the static grid to prepare (CSF: cloth codes, default `gfjax.csf.tuning.GRID`;
        SMRF: openings up to its largest value); overrides `max_window_m`.
      tiling: the tiles a tiled method's samples are cut into (`gfjax.tiling.tiles.Tiling`, None:
        its defaults), as its `filter` cuts them.
      defaults: float `(p,)` the values a fit starts from, is pulled toward and is guarded
        against, ordered as `method.bounds` (None: the method's fixed defaults; `gfjax tune`
        passes those the samples' terrain gives, `gfjax.adaptive`).
    """

    _defaults: np.ndarray | None = None         # problems pickled before they carried their own defaults

    @property
    def defaults(self) -> np.ndarray:
        """float32 `(p,)`: the start, the prior's centre and the guard's reference."""
        return self.method.defaults if self._defaults is None else self._defaults

    def __init__(self, samples: Sequence[Sample], *, config, max_window_m: float | None = None,
                 method: tuners.GradientTuner | None = None, max_batch: int = 8, grid: tuple[float, ...] | None = None,
                 tiling: tiling_lib.Tiling | None = None, defaults: Sequence[float] | np.ndarray | None = None):
        if not samples:
            raise InputError("no labelled samples to tune on")
        method = tuners.of_config(config) if method is None else method
        if defaults is not None:
            defaults = np.asarray(defaults, np.float32).reshape(len(method.bounds))
            for b, value in zip(method.bounds, defaults):
                if not b.lo < value < b.hi:
                    raise InputError(f"{b.name}: starting value {value:g} outside the tuning bounds ({b.lo:g}, {b.hi:g})")
            self._defaults = defaults
        if not isinstance(config, method.config_type):
            raise InputError(f"config: expected a {method.name} Config, got {type(config).__name__}")
        self.samples = list(samples)
        self.method = method
        grid = tuple(grid) if grid else (max_window_m,) if max_window_m else method.grid
        self.config = method.prepared_config(config, grid)
        if method.prepare_samples is not None:          # whole clouds (CSF), not tiles
            if not any(np.any(s.use) for s in self.samples):
                raise InputError("the labelled samples hold no usable point")
            self.buckets = [Bucket(prep, ref, cloud, core, shape) for prep, ref, cloud, core, shape in
                            method.prepare_samples(self.samples, self.config, max_batch=max_batch)]
            return
        tiles, owner = [], {}
        lattice = lattice_of(tiling, config.cell_m)
        for i, s in enumerate(self.samples):
            for tile in tiling_lib.split(s.xyz_m, **lattice._asdict(), use=s.use):
                owner[id(tile)] = i
                tiles.append(tile)
        if not tiles:
            raise InputError("the labelled samples hold no usable point")
        self.buckets: list[Bucket] = []
        for batch in batches_lib.batches(tiles, max_batch=max_batch):
            prep = _prepare_batch(batch.xyz, batch.valid, batch.hw, method=method, config=self.config,
                                  shape=batch.shape)
            b, cap = batch.valid.shape
            ref = np.zeros((b, cap), bool)
            core_index = np.full((b, cap), -1, np.int64)
            cloud = np.zeros(b, np.int32)
            for j, tile in enumerate(batch.tiles):
                i = owner[id(tile)]
                cloud[j] = i
                ref[j, :tile.n_points] = self.samples[i].ref_ground[tile.index]
                core_index[j, :tile.n_points] = np.where(tile.core, tile.index, -1)
            self.buckets.append(Bucket(prep, jnp.asarray(ref), jnp.asarray(cloud), core_index, batch.shape))

    @property
    def n_samples(self) -> int:
        return len(self.samples)

    def masks(self, point_masks: Sequence[np.ndarray] | None = None) -> tuple[jax.Array, ...]:
        """Per bucket, bool `(b, cap)`: the labelled core points that count.

        Args:
          point_masks: per sample a bool `(n,)` over its points (None: all of them).
        """
        out = []
        for bucket in self.buckets:
            mask = bucket.core_index >= 0
            if point_masks is not None:
                cloud = np.asarray(bucket.cloud)
                for j in range(mask.shape[0]):
                    pm = np.asarray(point_masks[cloud[j]], bool)
                    idx = bucket.core_index[j]
                    mask[j] &= np.where(idx >= 0, pm[np.maximum(idx, 0)], False)
            out.append(jnp.asarray(mask))
        return tuple(out)

    def covered(self) -> list[np.ndarray]:
        """Per sample a bool `(n,)`: the points labelled by some tile's core (all used points)."""
        out = [np.zeros(len(s.xyz_m), bool) for s in self.samples]
        for bucket in self.buckets:
            cloud = np.asarray(bucket.cloud)
            for j in range(cloud.shape[0]):
                idx = bucket.core_index[j]
                out[cloud[j]][idx[idx >= 0]] = True
        return out

    def labels(self, per_bucket_ground: Sequence[np.ndarray]) -> list[np.ndarray]:
        """Per sample a bool `(n,)` ground array from per-bucket `(b, cap)` labels (cores)."""
        out = [np.zeros(len(s.xyz_m), bool) for s in self.samples]
        for bucket, ground in zip(self.buckets, per_bucket_ground):
            cloud = np.asarray(bucket.cloud)
            ground = np.asarray(ground)
            for j in range(ground.shape[0]):
                idx = bucket.core_index[j]
                out[cloud[j]][idx[idx >= 0]] = ground[j][idx >= 0]
        return out
