"""PMF, the progressive morphological filter (Zhang et al. 2003), as JAX raster stages.

```python
import gfjax
result = gfjax.pmf.filter(gfjax.read("tile.laz"))     # values that follow the cloud (`adapt`)
result = gfjax.pmf.filter(cloud, config=gfjax.pmf.Config(max_window_m=17.0),
                          params=gfjax.pmf.Params(slope=0.5))
```
"""
from gfjax.method import Method
from gfjax.pmf.config import HIDES_LOW_OUTLIERS, PRESETS, RANGES, Config, Params, adapt
from gfjax.pmf.filter import Diagnostics, filter, warm
from gfjax.pmf.stages import TileDiagnostics

# A tile's core labels depend on its window only: a survey runs each tile once.
METHOD = Method("pmf", filter, Config, Params, PRESETS, RANGES, adapt=adapt, hides_low_outliers=HIDES_LOW_OUTLIERS, warm=warm, tiles=True,
                tile_labels=True, tuning="gradient")

__all__ = ["METHOD", "filter", "warm", "adapt", "Config", "Params", "PRESETS", "Diagnostics", "TileDiagnostics"]
