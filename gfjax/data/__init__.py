"""Data shipped with gfjax: the demo sample (see `README.md` in this folder for attribution).

```python
cloud = gfjax.read(gfjax.data.demo_sample())     # ISPRS reference sample 12, labelled
```
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["DEMO_SAMPLE", "demo_sample"]

DEMO_SAMPLE = "samp12-utm.laz"


def demo_sample() -> Path:
    """Path of the shipped demo sample: ISPRS filter-test reference sample 12 (urban, 52,119
    points, EPSG:32632, ground = class 2, object = class 0; CC BY 4.0, Sithole & Vosselman 2004)."""
    path = Path(str(resources.files(__name__) / DEMO_SAMPLE))
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the demo sample is missing from this gfjax installation")
    return path
