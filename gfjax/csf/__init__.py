"""CSF, the cloth simulation filter (Zhang et al. 2016), as a jitted JAX particle simulation.

```python
import gfjax
result = gfjax.csf.filter(gfjax.read("tile.laz"))        # cloth-simulation-filter defaults
result = gfjax.csf.filter(cloud, config=gfjax.csf.Config(rigidness=1),
                          params=gfjax.csf.Params(class_threshold_m=0.3))
```
"""
from gfjax.csf.config import (
    HIDES_LOW_OUTLIERS,
    MAX_THRESHOLD_M,
    PRESETS,
    RANGES,
    RELIEF_TIME_STEP,
    TREND_M,
    Config,
    Params,
    adapt,
)
from gfjax.csf.filter import Diagnostics, filter, survey_config, survey_halo, warm
from gfjax.csf.programs import TileDiagnostics, filter_points, grid_shape
from gfjax.method import Method

# The cloth settles over the whole cloud: a point's label can depend on points far away, so no
# finite halo reproduces one file's labels; a survey runs as one cloud when it fits in memory.
METHOD = Method("csf", filter, Config, Params, PRESETS, RANGES, adapt=adapt, hides_low_outliers=HIDES_LOW_OUTLIERS, warm=warm, whole_cloud=True,
                survey_config=survey_config, survey_halo=survey_halo, tuning="gradient")

__all__ = ["METHOD", "filter", "adapt", "warm", "survey_config", "survey_halo", "Config", "Params", "PRESETS", "TREND_M", "MAX_THRESHOLD_M", "RELIEF_TIME_STEP", "filter_points", "grid_shape",
           "Diagnostics", "TileDiagnostics"]
