"""`gfjax.vote.filter`: a point is ground when most of several classical filters say so.

Each voter runs with its own defaults, its values following the cloud (`gfjax.adaptive`, the
terrain measured once for all of them), its low outliers hidden and its ground spikes dropped
as it does alone; the vote then takes the majority of their labels (`majority`). The voters
run side by side on the processors while their memory fits (`Config.workers`): MASF's
triangulations and the raster programs of SMRF and PMF leave the interpreter free, so on two
cores the three take about the time of MASF alone. Filters err in different places (an opening's edge,
a cloth's bridge, an alpha shape's densification), so most of them rarely err at one point:
on the labelled files the vote passes all 29 and errs less than any of its voters
(`experiments/results/vote_select.md`, `corpus_eval.md`).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np

from gfjax import cache
from gfjax.adaptive import Terrain
from gfjax.io import columns
from gfjax.io.cloud import CloudView
from gfjax.method import Method
from gfjax.result import Result
from gfjax.tiling.tiles import Tiling
from gfjax.vote.config import Config

__all__ = ["filter", "warm", "majority", "Diagnostics", "Ballot"]


def majority(votes: np.ndarray) -> np.ndarray:
    """Bool `(n,)`: True where more than half of bool `(k, n)` `votes` are True; where exactly
    half are (an even `k`), the first row's vote."""
    votes = np.asarray(votes, dtype=bool)
    count = 2 * votes.sum(axis=0, dtype=np.int32)
    return np.where(count == votes.shape[0], votes[0], count > votes.shape[0])


class Diagnostics(NamedTuple):
    """Attributes:
      voters: the voters' method names, in the order of `votes`' rows.
      votes: bool `(k, n)`, each voter's ground labels.
    """

    voters: tuple[str, ...]
    votes: np.ndarray

    @property
    def agreement(self) -> np.ndarray:
        """Float `(n,)`: the share of voters that agree with the vote's label, 0.5-1."""
        ground = majority(self.votes)
        return (self.votes == ground).mean(axis=0)


class Ballot(NamedTuple):
    """What each voter settled on the cloud (`gfjax.adaptive.Settled`, None where its values
    were fixed), for `gfjax filter -v`."""

    voters: tuple[str, ...]
    settled: tuple[Any, ...]

    def describe(self) -> str:
        """One line per voter: the values its rules chose; the terrain once, first."""
        terrain = next((s.terrain for s in self.settled if s is not None and s.terrain is not None), None)
        lines = [] if terrain is None else [f"terrain: {terrain.describe()}"]
        for name, settled in zip(self.voters, self.settled):
            if settled is None or settled.terrain is None:
                lines.append(f"{name}: fixed settings (no rule applied)")
                continue
            lines.append(f"{name}: {'; '.join(settled.choices())}")
        return "\n".join(lines)


@cache.persistent
def filter(cloud: CloudView, *, config: Config | None = None, params: None = None, returns: str = "all",  # noqa: A001 (the package API name)
           progress: bool = False, tiling: Tiling | None = None, terrain: Terrain | None = None) -> Result:
    """Classify a cloud's ground points by the majority of several filters.

    Args:
      cloud: the point cloud (any units).
      config: which filters vote (default `Config()`: SMRF, MASF and PMF).
      params: none (the vote has no threshold; each voter keeps its own).
      returns: "all" or "last": which returns are filtered.
      progress: the voters' progress bars.
      tiling: the buffered tiles of the voters that tile (`Method.tiles`: SMRF and PMF cut the
        cloud, DMF its raster; `gfjax.tiling.tiles.Tiling`), None for their default.
      terrain: what the voters' values settle on (`gfjax.adaptive.Terrain`), None for the
        cloud's own (measured once for them all); a survey gives its own.

    Returns:
      `Result(ground, diagnostics, settled=Ballot, notes)`: `ground` bool `(n,)`, False for
      ignored points; `diagnostics` a `Diagnostics` of every voter's labels; each voter's notes,
      named.
    """
    from gfjax import adaptive, methods

    config = Config() if config is None else config
    voters = [methods.get(name) for name in config.names]
    # Measured once for every voter whose values follow the cloud, not once by each.
    if terrain is None and any(v.adapt is not None for v in voters):
        terrain = adaptive.measure_cloud(cloud, returns)

    def run(voter: Method) -> Result:
        shared = {"terrain": terrain} if voter.adapt is not None else {}
        return voter.filter(cloud, returns=returns, progress=progress, **shared, **_tiling(voter, tiling))

    workers = config.workers(_extent_m(cloud, returns), tiling)
    if workers > 1:
        with ThreadPoolExecutor(workers, thread_name_prefix="gfjax-vote") as pool:
            results = list(pool.map(run, voters))
    else:
        results = [run(voter) for voter in voters]
    votes = np.stack([np.asarray(r.ground, dtype=bool) for r in results])
    notes = tuple(f"{name}: {note}" for name, r in zip(config.names, results) for note in r.notes)
    return Result(ground=majority(votes), diagnostics=Diagnostics(config.names, votes),
                  settled=Ballot(config.names, tuple(r.settled for r in results)), notes=notes)


def _extent_m(cloud: CloudView, returns: str) -> tuple[float, float] | None:
    """The x, y extent of the cloud's used points [m], None without one."""
    use = cloud.filter_mask(returns)
    if not use.any():
        return None
    xy = cloud.xyz_m[:, :2] if use.all() else cloud.xyz_m[use, :2]
    span = columns.highs(xy) - columns.lows(xy)
    return float(span[0]), float(span[1])


def _tiling(voter: Method, tiling: Tiling | None) -> dict:
    """`{"tiling": tiling}` for a voter that tiles and a given tiling, else nothing."""
    return {"tiling": tiling} if voter.tiles and tiling is not None else {}


@cache.persistent
def warm(config: Config | None = None, params: None = None, *, progress: bool = False) -> int:
    """Load or compile every voter's programs (`gfjax warmup`); the number of programs."""
    from gfjax import methods

    config = Config() if config is None else config
    count = 0
    for name in config.names:
        warm_voter = methods.get(name).warm
        if warm_voter is not None:
            count += warm_voter(progress=progress)
    return count
