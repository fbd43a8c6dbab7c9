"""The vote's settings: which filters vote (each with its own defaults, following the cloud).

`experiments/vote_select.py` chose among the majorities of SMRF with two to four of MASF, PMF,
CSF and DMF, on the training files only: among those that pass every training file, the
lowest mean total error on the ISPRS training samples. That is SMRF, MASF, PMF and CSF
(ISPRS 2.98 %, 29 of 29 files). The default leaves CSF out: its cloth covers a whole file at
once, about 10 GiB for a 2 x 2 km tile (`csf.Config.memory_estimates`), which a default must
not ask for, and the three that remain scale with the tile like SMRF. Without CSF the vote
passes 29 of 29 files too, ISPRS 3.06 %, and has the lowest mean total error and type I over
the 29 files of every candidate (`experiments/results/vote_select.md`). SMRF is first: with an
even number of voters it breaks ties.
"""
from __future__ import annotations

import dataclasses

from gfjax import limits
from gfjax.errors import SettingError
from gfjax.limits import Range

__all__ = ["Config", "PRESETS", "RANGES", "VOTERS"]

VOTERS = "smrf,masf,pmf"
# The rule's own choice, CSF's cloth included: ISPRS 2.98 % against 3.06 %, on files whose cloth fits.
PRESETS = {"with-csf": {"voters": "smrf,masf,pmf,csf"}}
RANGES: dict[str, Range] = {}


@dataclasses.dataclass(frozen=True)
class Config:
    """Attributes:
      voters: comma-separated method names, each run with its defaults; a point is ground when
        more than half of them say so, and with a tie as the first says. At least one, each
        once, not the vote itself.
    """

    voters: str = VOTERS

    def __post_init__(self):
        from gfjax import methods

        names = self.names
        if not names:
            raise SettingError("voters: give at least one method, e.g. voters=smrf,masf,pmf", "voters")
        for name in names:
            if name == "vote" or name not in methods.PACKAGES:
                others = ", ".join(n for n in methods.PACKAGES if n != "vote")
                raise SettingError(f"voters: {name!r} cannot vote; choose from {others}", "voters")
        if len(set(names)) < len(names):
            raise SettingError(f"voters: each method votes once, got {self.voters!r}", "voters")

    @property
    def names(self) -> tuple[str, ...]:
        """The voters' method names, in order."""
        return tuple(name.strip() for name in self.voters.split(",") if name.strip())

    def memory_estimates(self, extent_m: tuple[float, float] | None = None, tiling=None) -> list[limits.Estimate]:
        """Every voter's estimates with its defaults, `tiling` for those that tile: each must fit
        the memory budget alone (voters run side by side only where theirs fit together, `workers`)."""
        return [e for estimates in self._estimates(extent_m, tiling) for e in estimates]

    def workers(self, extent_m: tuple[float, float] | None = None, tiling=None) -> int:
        """How many voters run at once: one a processor, up to one each, fewer while the largest
        allocations of that many voters (the largest such voters: any may meet) exceed the
        memory budget together (`limits.memory_budget_bytes`)."""
        largest = sorted((max((e.n_bytes for e in estimates), default=0.0)
                          for estimates in self._estimates(extent_m, tiling)), reverse=True)
        workers = min(len(largest), limits.processors())
        budget = limits.memory_budget_bytes()
        while workers > 1 and sum(largest[:workers]) > budget:
            workers -= 1
        return max(1, workers)

    def _estimates(self, extent_m, tiling) -> list[list[limits.Estimate]]:
        """Each voter's estimates with its defaults, in the voters' order."""
        from gfjax import methods

        out = []
        for voter in map(methods.get, self.names):
            estimates = getattr(voter.Config(), "memory_estimates", None)
            if estimates is None:
                out.append([])
            else:
                out.append(estimates(extent_m, tiling=tiling) if voter.tiles else estimates(extent_m))
        return out
