"""The one return type of every method's `filter`."""
from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np


class Result(NamedTuple):
    """Outcome of a ground filter on one cloud.

    Attributes:
      ground: bool, shape `(n,)`, one per point of the input cloud; True = ground (ASPRS 2).
        Points the filter ignores (noise classes 7 and 18, withheld) are False.
      diagnostics: a per-method NamedTuple of intermediate rasters/arrays (host numpy), or None.
      instance_id: optional uint32 `(n,)` object-instance id per point, 0 outside any object.
      settled: the settings the run used where some followed the cloud
        (`gfjax.adaptive.Settled`: the config, the params, what the rules chose and the
        terrain they read), or None when every setting was given.
      notes: what a user should know of this run (a fallback it took), one line each; the
        command line says them on stderr.
    """

    ground: np.ndarray
    diagnostics: Any = None
    instance_id: np.ndarray | None = None
    settled: Any = None
    notes: tuple[str, ...] = ()
