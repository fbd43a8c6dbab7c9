"""The one way a method's `Params` field is declared: a traced float32 scalar with a default.

```python
class Params(eqx.Module):
    slope: Float[Array, ""] = param(0.15)
```
Python numbers, numpy and JAX values given for it become float32 0-d JAX arrays, so `Params`
is a pytree optax can update and `jax.jit` traces (never a static value that recompiles).
"""
from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["f32", "param"]


def f32(value) -> Float[Array, ""]:
    """`value` as a float32 JAX array."""
    return jnp.asarray(value, dtype=jnp.float32)


def param(default: float):
    """An `eqx.Module` field holding a float32 scalar, `default` when not given."""
    return eqx.field(default=default, converter=f32)
