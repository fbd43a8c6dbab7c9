"""Array type aliases used across gfjax (jaxtyping).

Shape letters: `n` points, `h w` raster rows x cols (row 0 = max northing), `b` tiles,
`k` neighbours, `c` features.
"""
import numpy as np
from jaxtyping import Array, Bool, Float, Int

Points = Float[Array, "n 3"]        # local x, y, z in metres (float32 inside JAX)
XY = Float[Array, "n 2"]            # local x, y in metres
Heights = Float[Array, " n"]        # z or heights in metres
PointMask = Bool[Array, " n"]       # per-point flag (valid, ground, ...)
Raster = Float[Array, "h w"]        # a value per cell, metres unless stated
Mask = Bool[Array, "h w"]           # a flag per cell (valid, object, ...)
Labels = Int[Array, "h w"]          # component ids per cell, 0 = background
Host = Array | np.ndarray           # a JAX or a host numpy array (a tile batch arrives from the tiler as numpy)

__all__ = ["Points", "XY", "Heights", "PointMask", "Raster", "Mask", "Labels", "Host"]
