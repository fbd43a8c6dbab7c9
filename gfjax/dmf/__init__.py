"""DMF: the data-driven morphological filter (Wu et al. 2025), SPEC section 3.

```python
import gfjax
result = gfjax.dmf.filter(cloud)                         # Result(ground, diagnostics, instance_id)
result = gfjax.dmf.filter(cloud, config=gfjax.dmf.Config(basal_stop="per_node"))
```
"""
from gfjax.dmf.config import HIDES_LOW_OUTLIERS, PRESETS, RANGES, Config, Params, adapt, survey_halo
from gfjax.dmf.filter import Diagnostics, filter, survey_config, warm  # noqa: A004
from gfjax.method import Method

# Its NGNEM raster is cut into buffered tiles, but the labels of a tile's points come from
# the patches of the whole raster: a survey runs whole files with halos, not a lattice.
METHOD = Method("dmf", filter, Config, Params, PRESETS, RANGES, adapt=adapt, hides_low_outliers=HIDES_LOW_OUTLIERS, warm=warm, tiles=True,
                survey_config=survey_config, survey_halo=survey_halo, tuning="grid")

__all__ = ["METHOD", "filter", "adapt", "warm", "Config", "Params", "PRESETS", "Diagnostics", "survey_config"]
