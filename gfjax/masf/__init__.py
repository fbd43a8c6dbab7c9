"""MASF: multiscale filtering with a modified 3D alpha shape (Cao et al. 2024, Remote Sens. 16:1443).

```python
import gfjax
result = gfjax.masf.filter(gfjax.read("tile.laz"))            # alpha_max 25 m, step 2 m, ST 0.05
config, params = gfjax.methods.make_config_and_params(gfjax.masf, preset="paper-samp42")
result = gfjax.masf.filter(cloud, config=config, params=params)
```
"""
from gfjax.masf.config import HIDES_LOW_OUTLIERS, PAPER_TABLE3, PRESETS, RANGES, Config, Params, adapt
from gfjax.masf.filter import Diagnostics, filter, filter_points
from gfjax.method import Method

METHOD = Method("masf", filter, Config, Params, PRESETS, RANGES, adapt=adapt, hides_low_outliers=HIDES_LOW_OUTLIERS, tuning="grid")

__all__ = ["METHOD", "filter", "adapt", "filter_points", "Config", "Params", "PRESETS", "PAPER_TABLE3", "Diagnostics"]
