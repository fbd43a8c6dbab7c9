"""The one shape of a method's `Params`: traced float32 scalars with defaults, one range check.

```python
class Params(gfjax.params.Params):
    ranges = RANGES                      # the method's `gfjax.limits.Range` per field
    slope: Float[Array, ""] = param(0.15)
```
Python numbers, numpy and JAX values given for a field become float32 0-d JAX arrays, so
`Params` is a pytree optax can update and `jax.jit` traces (never a static value that
recompiles); `check()` tests concrete values against `ranges` outside `jit`.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from gfjax import limits

__all__ = ["Params", "declared_defaults", "f32", "param"]


def f32(value) -> Float[Array, "*batch"]:
    """`value` as a float32 JAX array: a scalar, or a batch of them to `vmap` over."""
    if isinstance(value, (jax.Array, jax.core.Tracer)):
        return jnp.asarray(value, dtype=jnp.float32)
    # A host value is rounded by numpy and put on the device as it is: no conversion program
    # to compile, which a fresh process would otherwise do for its first Params (0.04 s).
    return jax.device_put(np.asarray(value, dtype=np.float32))


def param(default: float):
    """An `eqx.Module` field holding a float32 scalar, `default` when not given."""
    return eqx.field(default=default, converter=f32)


def declared_defaults(params_type: type) -> dict[str, float]:
    """`{field: default}` of a `Params` class as declared (the Python numbers, not their float32)."""
    return {f.name: f.default for f in dataclasses.fields(params_type)}


class Params(eqx.Module):
    """Base of every method's traced thresholds; a subclass sets `ranges` and its fields."""

    ranges: ClassVar[Mapping[str, limits.Range]] = {}

    def check(self) -> None:
        """Range checks on concrete values (call outside jit): raises `SettingError` naming the key."""
        limits.check_fields(self, self.ranges)
