"""Shared, cached inputs of the tuning tests: a labelled crop of the shipped sample, small
synthetic tiles, one static config (few compiles)."""
from __future__ import annotations

import functools
from importlib.resources import files

import numpy as np

import gfjax
from gfjax.smrf import Config
from gfjax.smrf import tuning as tsmrf
from gfjax.tiling import batches
from gfjax.tiling import tiles as tiling
from gfjax.tune.problem import Problem, Sample

CONFIG = Config(window_m=6.0)          # 6 openings: small compiles
WINDOWS = (4.0, 6.0)
CROP_M = 56.0                          # one 64 x 64 cell bucket at 1 m


@functools.cache
def crop_cloud() -> gfjax.Cloud:
    """A 56 x 56 m urban crop of ISPRS sample 12 (shipped in gfjax/data): ~4,000 points,
    46 % ground (class 2), buildings and streets."""
    cloud = gfjax.read(files("gfjax.data") / "samp12-utm.laz")
    xyz = cloud.xyz_m
    x0, y0 = xyz[:, 0].min() + 80.0, xyz[:, 1].min() + 40.0
    keep = (xyz[:, 0] >= x0) & (xyz[:, 0] < x0 + CROP_M) & (xyz[:, 1] >= y0) & (xyz[:, 1] < y0 + CROP_M)
    return gfjax.Cloud.from_xyz(xyz[keep], classification=cloud.classification[keep])


@functools.cache
def crop_sample() -> Sample:
    return Sample.from_cloud(crop_cloud())


@functools.cache
def crop_batch() -> batches.TileBatch:
    s = crop_sample()
    tiles = tiling.split(s.xyz_m, **tiling.Tiling().lattice(CONFIG.cell_m)._asdict(), use=s.use)
    (batch,) = list(batches.batches(tiles))
    return batch


@functools.cache
def crop_prepared() -> tsmrf.Prepared:
    b = crop_batch()
    return tsmrf.prepare_tile(b.xyz[0], b.valid[0], b.hw[0], config=CONFIG, shape=b.shape)


def synthetic_sample(kind: str, seed: int = 0) -> Sample:
    """A 40 x 40 m tile: "flat" (gently sloping ground, all labelled ground), "roof" (a
    10 m block over the whole tile, no ground label), or "mixed" (ground with a building)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, (1600, 2))
    z = 100.0 + 0.05 * xy[:, 0] + rng.normal(0, 0.03, len(xy))
    ref = np.ones(len(xy), bool)
    if kind == "roof":
        z = z + 10.0
        ref[:] = False
    elif kind == "mixed":
        inside = (np.abs(xy[:, 0] - 20) < 6) & (np.abs(xy[:, 1] - 20) < 6)
        z = np.where(inside, z + 8.0, z)
        ref = ~inside
    xyz = np.column_stack([xy + [500_000.0, 5_400_000.0], z])
    return Sample(kind, xyz, ref, np.ones(len(xy), bool))


@functools.cache
def problem(names: tuple[str, ...]) -> Problem:
    """A Problem over `("crop", "flat", "roof", "mixed", "rough")` members (cached per tuple)."""
    samples = [crop_sample() if n == "crop" else rough_sample() if n == "rough" else synthetic_sample(n)
               for n in names]
    return Problem(samples, config=CONFIG, max_window_m=max(WINDOWS))


def rough_sample(seed: int = 0) -> Sample:
    """A 40 x 40 m all-ground tile whose ground is rough (0.4 m noise) on a 0.1 slope: the
    default threshold (0.5 m) calls many ground points objects, a larger one fixes them
    everywhere (a case the guard must keep)."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, (1600, 2))
    z = 100.0 + 0.1 * xy[:, 0] + rng.normal(0, 0.4, len(xy))
    xyz = np.column_stack([xy + [500_000.0, 5_400_000.0], z])
    return Sample("rough", xyz, np.ones(len(xy), bool), np.ones(len(xy), bool))
