"""gfjax: ground filtering of airborne LiDAR point clouds as JAX array code.

```python
import gfjax
cloud = gfjax.read("tile.laz")
result = gfjax.smrf.filter(cloud)
gfjax.write(cloud.with_ground(result.ground), "out.laz")
```
Method packages (`gfjax.smrf`, `gfjax.dmf`, ...) are imported on first attribute access.
Importing gfjax changes no JAX setting and writes nothing; the first call of a method's
`filter` or `warm` keeps compiled programs in `~/.cache/gfjax` for later processes
(`gfjax.cache`; `GFJAX_CACHE=0` turns that off).
"""
from __future__ import annotations

import importlib

from gfjax.io.cloud import Cloud
from gfjax.methods import PACKAGES as _PACKAGES
from gfjax.methods import collector_paused as _collector_paused
from gfjax.result import Result

__version__ = "0.1.0"

_LAZY = {"data", "bench", "raster", "dtm", "metrics", "tune", "io", "tiling", "methods", "method", "cache", "aot",
         *(package.removeprefix("gfjax.") for package in _PACKAGES.values())}
_LAZY_FUNCS = {"read": "gfjax.io.las", "write": "gfjax.io.las", "Tiling": "gfjax.tiling.tiles"}


def __getattr__(name: str):
    if name in _LAZY:
        with _collector_paused():           # a method's import, as `gfjax.methods.get` does it
            return importlib.import_module(f"gfjax.{name}")
    if name in _LAZY_FUNCS:
        return getattr(importlib.import_module(_LAZY_FUNCS[name]), name)
    raise AttributeError(f"module 'gfjax' has no attribute {name!r}")


__all__ = ["Cloud", "Result", "Tiling", "__version__", "read", "write", *sorted(_LAZY)]
