"""CSF with a relaxed class threshold; time step and rigidness on a grid of cached cloths.

CSF (Zhang et al. 2016, Sec. 2.3; `gfjax.csf`) labels a point ground when its distance to the
simulated cloth is below the class threshold, `|d| < class_threshold_m` (c2cdist.cpp). The
threshold acts only at that test; the relaxed ground weight is

    sigmoid((class_threshold_m - |d|) / T)      (= 1 - sigmoid((|d| - t) / T)),

so its gradient is exact and never zero while any point lies near the threshold.

The time step and the rigidness act only through the cloth simulation (`gfjax.csf.cloth`),
whose stopping rule (largest displacement under 5 mm, CSF.cpp `do_cloth`) is a
`lax.while_loop`: reverse-mode gradients do not exist through it, and the rigidness is a
static loop count. Both are therefore searched on a small grid (SPEC section 7): each grid
cloth is simulated once per sample with the plain filter's own pipeline
(`gfjax.csf.filter_points`), and only the point-to-cloth distances `d` are kept. They are
never reported as gradient-fitted.

A grid value ("cloth") is the float code `10 * rigidness + time_step` (rigidness 3, time step
0.65 -> 30.65), so the tuning loop's single static parameter can name both; `decode` inverts it.

With `temperature=None` the labels are `valid & gfjax.csf.stages.is_ground(d, t)` on the same
`d` the plain filter computes, i.e. `gfjax.csf.filter` bit for bit (tested).

Simulations take 0.3-50 s per ISPRS sample; `cloth_cache(folder)` keeps the distances on disk
(one `.npy` per sample and cloth, keyed by the points, the CSF config, the cloth and the gfjax
version).
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from gfjax import csf
from gfjax._types import PointMask, Points
from gfjax.csf import stages
from gfjax.csf.config import BUFFER_PX
from gfjax.tiling import buckets
from gfjax.tune import relax
from gfjax.tune.params import bound
from gfjax.tune.tuners import GradientTuner

__all__ = ["TUNER", "BOUNDS", "UNITS", "TIME_STEPS", "RIGIDNESS", "GRID", "TuneConfig", "Prepared", "encode", "decode",
           "cloth_distances", "sample_distances", "prepare_samples", "ground_weight", "cloth_cache"]

BOUNDS = (bound(csf.Params, "class_threshold_m", 0.1, 1.5, "m"),)
UNITS = {"class_threshold_m": "m", "time_step": "1 (simulation time step)",
         "rigidness": "1 (spring relaxations per step)"}
TIME_STEPS = (0.5, 0.65, 0.8)
RIGIDNESS = (1, 2, 3)


def encode(time_step: float, rigidness: int) -> float:
    """Grid code `10 * rigidness + time_step` of a cloth (time step in (0, 10))."""
    if not 0 < time_step < 10:
        raise ValueError(f"time_step must lie in (0, 10) to be encoded, got {time_step}")
    return round(10.0 * int(rigidness) + float(time_step), 6)


def decode(code: float) -> tuple[float, int]:
    """`(time_step, rigidness)` of a grid code."""
    rigidness = int(code // 10)
    return round(float(code) - 10.0 * rigidness, 6), rigidness


GRID = tuple(encode(t, r) for r in RIGIDNESS for t in TIME_STEPS)


@dataclasses.dataclass(frozen=True)
class TuneConfig:
    """Static settings of a CSF tuning problem (hashable).

    Attributes:
      csf: the filter's static config (its `rigidness` is replaced by each cloth's).
      cloths: grid codes of the prepared cloths, in the order of `Prepared.distance`.
    """

    csf: csf.Config
    cloths: tuple[float, ...]

    def index(self, code: float) -> int:
        """Row of `Prepared.distance` holding cloth `code` (ValueError if not prepared)."""
        for k, c in enumerate(self.cloths):
            if abs(c - code) < 1e-6:
                return k
        t, r = decode(code)
        raise ValueError(f"cloth time_step={t}, rigidness={r} (code {code}) was not prepared; "
                         f"prepared: {', '.join(str(decode(c)) for c in self.cloths)}")


class Prepared(NamedTuple):
    """One sample's parameter-free CSF data (padded to a capacity).

    Attributes:
      distance: float32 `(cloths, cap)` signed distance `d` of each point to each grid cloth [m]
        (`gfjax.csf.stages.height_above_cloth`; 0 on padding).
      valid: bool `(cap,)` points the filter sees.
    """

    distance: Float[Array, "k n"]
    valid: PointMask


@functools.partial(jax.jit, static_argnames=("config", "shape"))
def cloth_distances(xyz: Points, valid: PointMask, time_step: Float[Array, ""], *, config: csf.Config,
                    shape: tuple[int, int]) -> tuple[Float[Array, " n"], PointMask]:
    """The plain filter's point-to-cloth distance `d` `(n,)` [m] and its labels at the default
    threshold, bool `(n,)` (a check that `d` is the filter's).

    Runs `gfjax.csf.filter_points` (arguments as there) and evaluates the final cloth at the
    points with the filter's own origin and bilinear interpolation.
    """
    params = csf.Params(time_step=time_step)
    ground, diag = csf.filter_points(xyz, valid, params, config=config, shape=shape)
    xy, u = xyz[:, :2], -xyz[:, 2]
    big = jnp.asarray(jnp.inf, xyz.dtype)
    lo = jnp.min(jnp.where(valid[:, None], xy, big), axis=0)
    rel = xy - (lo - BUFFER_PX * jnp.float32(config.cell_m))[None, :]
    return stages.height_above_cloth(rel, u, diag.cloth_u, cell_m=config.cell_m), ground


_CACHE: list[Path | None] = [None]


@contextlib.contextmanager
def cloth_cache(folder: str | os.PathLike | None) -> Iterator[None]:
    """Within the block, `sample_distances` reads and writes distances under `folder`."""
    previous, _CACHE[0] = _CACHE[0], None if folder is None else Path(folder)
    try:
        yield
    finally:
        _CACHE[0] = previous


def sample_distances(xyz_m: np.ndarray, use: np.ndarray, *, config: csf.Config,
                     cloths: Sequence[float]) -> np.ndarray:
    """Point-to-cloth distances of one cloud for each grid cloth, float32 `(cloths, n)` [m].

    The cloud is framed exactly as `gfjax.csf.filter` frames it (origin at the minimum of the
    used points, float32 local metres less the trend where `config.trend_m` asks,
    `grid_shape`), so the distances are the filter's.

    Args:
      xyz_m: float64 `(n, 3)` [m]; use: bool `(n,)` points the filter sees (at least one).
      config: CSF static settings; cloths: grid codes (`encode`).
    """
    from gfjax import __version__
    from gfjax.csf.filter import detrended

    use = np.asarray(use, bool)
    origin = xyz_m[use].min(axis=0)
    local, _ = detrended(xyz_m - origin, use, config)
    shape = csf.grid_shape(local, use, cell_m=config.cell_m)
    out = np.zeros((len(cloths), len(local)), np.float32)
    for k, code in enumerate(cloths):
        time_step, rigidness = decode(code)
        cfg = dataclasses.replace(config, rigidness=rigidness)
        path = None
        if _CACHE[0] is not None:
            key = hashlib.sha256(local.tobytes() + use.tobytes() + repr((cfg, time_step, __version__)).encode())
            path = _CACHE[0] / f"csf_cloth_{key.hexdigest()[:20]}.npy"
            if path.exists():
                out[k] = np.load(path)
                continue
        gap, _ = cloth_distances(jnp.asarray(local), jnp.asarray(use), jnp.float32(time_step), config=cfg,
                                 shape=shape)
        out[k] = np.asarray(gap)
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.tmp.npy")
            np.save(tmp, out[k])
            tmp.replace(path)
    return out


def prepare_samples(samples: Sequence, config: TuneConfig, *, max_batch: int = 8) -> list[tuple]:
    """Whole samples (CSF filters a cloud in one piece) batched by point capacity.

    Returns:
      Per batch `(prep, ref, cloud, core_index, shape)`: a `Prepared` with a leading batch axis,
      bool `(b, cap)` reference ground, int32 `(b,)` sample index, int64 `(b, cap)` point index
      of used points (-1 elsewhere), and `(cloths, cap)`.
    """
    by_cap: dict[int, list[int]] = {}
    for i, s in enumerate(samples):
        if np.any(s.use):
            by_cap.setdefault(buckets.capacity_bucket(int(len(s.xyz_m))), []).append(i)
    out = []
    for cap, members in sorted(by_cap.items()):
        for start in range(0, len(members), max_batch):
            chunk = members[start:start + max_batch]
            b = len(chunk)
            dist = np.zeros((b, len(config.cloths), cap), np.float32)
            valid = np.zeros((b, cap), bool)
            ref = np.zeros((b, cap), bool)
            core = np.full((b, cap), -1, np.int64)
            for j, i in enumerate(chunk):
                s = samples[i]
                n = len(s.xyz_m)
                dist[j, :, :n] = sample_distances(s.xyz_m, s.use, config=config.csf, cloths=config.cloths)
                valid[j, :n] = s.use
                ref[j, :n] = s.ref_ground
                core[j, :n] = np.where(s.use, np.arange(n), -1)
            prep = Prepared(jnp.asarray(dist), jnp.asarray(valid))
            out.append((prep, jnp.asarray(ref), jnp.asarray(np.asarray(chunk, np.int32)), core,
                        (len(config.cloths), cap)))
    return out


def ground_weight(prep: Prepared, class_threshold_m: Float[Array, ""], cloth: int | jax.Array, *,
                  temperature: float | Float[Array, ""] | None = None) -> PointMask | Float[Array, " n"]:
    """CSF's class test on a prepared sample with grid cloth `cloth` (row of `prep.distance`,
    may be traced): hard labels (`temperature=None`, `valid & |d| < t` as the plain filter) or
    relaxed ground weights `sigmoid((t - |d|) / T)` in [0, 1], float `(n,)`; 0 where `~valid`."""
    d = prep.distance[cloth]
    if temperature is None:
        return prep.valid & stages.is_ground(d, class_threshold_m)
    weight = relax.less_equal(jnp.abs(d), class_threshold_m, temperature)
    return jnp.where(prep.valid, weight, jnp.zeros((), weight.dtype))


def _ground_weight(prep, values, *, config, static_px, temperature):
    del config
    return ground_weight(prep, values[0], static_px, temperature=temperature)


def _grid_values(code: float) -> dict:
    time_step, rigidness = decode(code)
    return {"time_step": time_step, "rigidness": rigidness}


TUNER = GradientTuner(
    name="csf", bounds=BOUNDS, units=UNITS, config_type=csf.Config, static="cloth",
    grid=GRID, prepare_tile=None, ground_weight=_ground_weight,
    static_px=lambda config, value: config.index(value),
    default_static=lambda config: encode(float(csf.Params().time_step), getattr(config, "csf", config).rigidness),
    prepared_config=lambda config, grid: TuneConfig(config, tuple(sorted({*grid, encode(
        float(csf.Params().time_step), config.rigidness)}))),
    prepare_samples=prepare_samples, static_values=_grid_values, grid_keys=("time_step", "rigidness"),
    from_keys=lambda requested: tuple(encode(t, r) for r in requested.get("rigidness", RIGIDNESS)
                                      for t in requested.get("time_step", TIME_STEPS)),
    static_note="time_step and rigidness act through the cloth simulation, a while loop with a "
                "displacement stopping rule (no reverse-mode gradient; rigidness is a loop count): "
                "grid search over cloths simulated once per sample, never gradient-fitted")
