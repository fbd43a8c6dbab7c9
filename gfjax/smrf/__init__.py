"""SMRF, the simple morphological filter (Pingel, Clarke & McBride 2013), as JAX raster stages.

```python
import gfjax
result = gfjax.smrf.filter(gfjax.read("tile.laz"))   # PDAL filters.smrf's defaults, the cell from the spacing
result.settled.chosen                                    # {"cell_m": 1.0}: what followed the cloud (`adapt`)
result = gfjax.smrf.filter(cloud, config=gfjax.smrf.Config(window_m=12.0),
                           params=gfjax.smrf.Params(slope=0.2))
result = gfjax.smrf.filter(cloud, tiling=gfjax.Tiling(tile_size_m=250.0, buffer_m=40.0))
```
"""
from gfjax.method import Method
from gfjax.smrf.config import HIDES_LOW_OUTLIERS, PRESETS, RANGES, Config, Params, adapt
from gfjax.smrf.filter import Diagnostics, filter, warm
from gfjax.smrf.stages import TileDiagnostics

# A tile's core labels depend on its window only: a survey runs each tile once.
METHOD = Method("smrf", filter, Config, Params, PRESETS, RANGES, adapt=adapt, hides_low_outliers=HIDES_LOW_OUTLIERS, warm=warm, tiles=True,
                tile_labels=True, tuning="gradient")

__all__ = ["METHOD", "filter", "warm", "adapt", "Config", "Params", "PRESETS", "Diagnostics", "TileDiagnostics"]
