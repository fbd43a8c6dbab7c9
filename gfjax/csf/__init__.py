"""CSF, the cloth simulation filter (Zhang et al. 2016), as a jitted JAX particle simulation.

```python
import gfjax
result = gfjax.csf.filter(gfjax.read("tile.laz"))        # cloth-simulation-filter defaults
result = gfjax.csf.filter(cloud, config=gfjax.csf.Config(rigidness=1),
                          params=gfjax.csf.Params(class_threshold_m=0.3))
```
"""
from gfjax.csf.config import PRESETS, Config, Params
from gfjax.csf.filter import Diagnostics, TileDiagnostics, filter, filter_points, grid_shape, warm

__all__ = ["filter", "warm", "Config", "Params", "PRESETS", "filter_points", "grid_shape", "Diagnostics",
           "TileDiagnostics"]
