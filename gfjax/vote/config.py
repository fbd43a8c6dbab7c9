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
        """Every voter's estimates with its defaults, `tiling` for those that tile: they run one
        after the other, so the largest of them is what the vote needs."""
        from gfjax import methods

        out: list[limits.Estimate] = []
        for voter in map(methods.get, self.names):
            estimates = getattr(voter.Config(), "memory_estimates", None)
            if estimates is not None:
                out += estimates(extent_m, tiling=tiling) if voter.tiles else estimates(extent_m)
        return out
