"""A majority vote of classical filters: SMRF, MASF and PMF by default.

```python
import gfjax
result = gfjax.vote.filter(gfjax.read("tile.laz"))          # each voter with its own defaults
result.diagnostics.agreement                                   # (n,) share of voters agreeing, 0.5-1
result = gfjax.vote.filter(cloud, config=gfjax.vote.Config(voters="smrf,masf,pmf,csf"))
```
"""
from gfjax.method import Method
from gfjax.vote.config import PRESETS, RANGES, VOTERS, Config
from gfjax.vote.filter import Ballot, Diagnostics, filter, majority, warm

# `tiling` goes to the voters that tile; the vote's labels depend on more than a tile's window
# (MASF's do), so a survey gives each file a halo, and its terrain, so the voters' values are
# the survey's in every window.
METHOD = Method("vote", filter, Config, None, PRESETS, RANGES, warm=warm, tiles=True, takes_terrain=True)

__all__ = ["METHOD", "filter", "warm", "majority", "Config", "VOTERS", "PRESETS", "Diagnostics", "Ballot"]
