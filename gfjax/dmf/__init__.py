"""DMF: the data-driven morphological filter (Wu et al. 2025), SPEC section 3.

```python
import gfjax
result = gfjax.dmf.filter(cloud)                         # Result(ground, diagnostics, instance_id)
result = gfjax.dmf.filter(cloud, config=gfjax.dmf.Config(basal_stop="per_node"))
```
"""
from gfjax.dmf.config import PRESETS, Config, Params, adapt
from gfjax.dmf.filter import Diagnostics, filter, survey_config, warm  # noqa: A004

__all__ = ["filter", "adapt", "warm", "Config", "Params", "PRESETS", "Diagnostics", "survey_config"]
