"""The one shape of a method's `Params`: traced float32 scalars with defaults, one range check.

```python
class Params(gfjax.params.Params):
    ranges = RANGES                      # the method's `gfjax.limits.Range` per field
    slope: Float[Array, ""] = param(0.15)
```
Python numbers, numpy and JAX values given for a field become float32 0-d JAX arrays, so
`Params` is a pytree optax can update and `jax.jit` traces (never a static value that
recompiles); `check()` tests concrete values against `ranges` outside `jit`.

A subclass is a frozen dataclass registered as a pytree when it is defined: what an
`equinox.Module` would give, without importing equinox (0.1 s) into every classical filter's
process. As an equinox module's, a field's conversion runs when `Params` is built, not when
JAX rebuilds it from its leaves (tracers, batches, `None` placeholders stay as they are).
"""
from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import ClassVar

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
    """A `Params` field holding a float32 scalar, `default` when not given."""
    return dataclasses.field(default=default)


def declared_defaults(params_type: type) -> dict[str, float]:
    """`{field: default}` of a `Params` class as declared (the Python numbers, not their float32)."""
    return {f.name: f.default for f in dataclasses.fields(params_type)}


def _flatten(params: Params):
    names = params.__dataclass_fields__
    return tuple((jax.tree_util.GetAttrKey(name), getattr(params, name)) for name in names), None


def _unflatten(cls: type, _, leaves) -> Params:
    params = object.__new__(cls)
    for name, leaf in zip(cls.__dataclass_fields__, leaves):
        object.__setattr__(params, name, leaf)
    return params


class Params:
    """Base of every method's traced thresholds; a subclass sets `ranges` and its fields."""

    ranges: ClassVar[Mapping[str, limits.Range]] = {}
    # The fields are annotated with what they hold once converted; `__init__` takes numbers too,
    # so a runtime type checker (jaxtyping's, in the tests) leaves its arguments alone.
    __no_type_check__: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        dataclasses.dataclass(frozen=True, repr=False)(cls)
        jax.tree_util.register_pytree_with_keys(cls, _flatten, functools.partial(_unflatten, cls))

    def __post_init__(self):
        for name in self.__dataclass_fields__:
            object.__setattr__(self, name, f32(getattr(self, name)))

    def __repr__(self) -> str:
        fields = ", ".join(f"{name}={_short(getattr(self, name))}" for name in self.__dataclass_fields__)
        return f"{type(self).__name__}({fields})"

    def check(self) -> None:
        """Range checks on concrete values (call outside jit): raises `SettingError` naming the key."""
        limits.check_fields(self, self.ranges)


def _short(value) -> str:
    """`0.15` for a concrete scalar, `float32[3]` for a batch or a tracer under `jit`."""
    if isinstance(value, jax.Array) and not isinstance(value, jax.core.Tracer) and value.ndim == 0:
        return f"{float(value):g}"
    shape = getattr(value, "shape", None)
    return repr(value) if shape is None else f"{getattr(value, 'dtype', '')}{list(shape)}"
