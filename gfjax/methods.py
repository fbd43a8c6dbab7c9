"""The registry of ground-filtering methods, and `--set key=value` handling.

Every method package (`gfjax.smrf`, `gfjax.dmf`, ...) exposes, at its top level:

- `filter(cloud, *, config=None, params=None, returns="all", progress=False) -> Result`
- `Config`: a frozen dataclass of static values (shapes, loop counts, cell sizes) [metres].
- `Params`: an `eqx.Module` of traced scalars (thresholds optax may tune) [metres], or None.
- `PRESETS`: dict of preset name -> dict of overrides (may be empty).

The registry imports a method lazily, so `gfjax info` does not pay for every method.
"""
from __future__ import annotations

import dataclasses
import importlib
from types import ModuleType
from typing import Any

METHODS: dict[str, str] = {
    "smrf": "gfjax.smrf",
    "dmf": "gfjax.dmf",
    "masf": "gfjax.masf",
    "pmf": "gfjax.pmf",
    "csf": "gfjax.csf",
    "sparsegf": "gfjax.sparsegf",
}


def available() -> list[str]:
    """Names of the methods whose package is importable."""
    names = []
    for name in METHODS:
        try:
            module = importlib.import_module(METHODS[name])
        except ImportError:
            continue
        if hasattr(module, "filter"):
            names.append(name)
    return names


def get(name: str) -> ModuleType:
    """The method package for `name` (raises ValueError naming the choices)."""
    if name not in METHODS:
        raise ValueError(f"--method: unknown method {name!r}; choose from {', '.join(METHODS)}")
    try:
        module = importlib.import_module(METHODS[name])
    except ImportError as err:
        raise ValueError(f"--method: method {name!r} is not available in this build ({err})") from err
    if not hasattr(module, "filter"):
        raise ValueError(f"--method: method {name!r} is not implemented yet")
    return module


def _parse_value(text: str, current: Any) -> Any:
    if isinstance(current, bool):
        if text.lower() in ("1", "true", "yes", "on"):
            return True
        if text.lower() in ("0", "false", "no", "off"):
            return False
        raise ValueError(f"expected true/false, got {text!r}")
    if isinstance(current, int):
        return int(text)
    if isinstance(current, float) or _is_scalar_array(current):
        return float(text)
    if isinstance(current, str):
        return text
    if current is None:
        for kind in (int, float):
            try:
                return kind(text)
            except ValueError:
                pass
        return text
    raise ValueError(f"cannot set a value of type {type(current).__name__} from the command line")


def _is_scalar_array(value: Any) -> bool:
    return hasattr(value, "shape") and getattr(value, "shape", None) == ()


def make_config_and_params(method: ModuleType, overrides: dict[str, str] | None = None,
                           preset: str | None = None) -> tuple[Any, Any]:
    """Build a method's `Config` and `Params` from a preset and `key=value` strings.

    Keys are matched against the fields of `Config` and of `Params`. An unknown key, an
    unknown preset or a value that does not parse raises `ValueError` naming the option.
    Range checks are the method's own (`Config.__post_init__` / its `filter`).
    """
    config = method.Config()
    params_cls = getattr(method, "Params", None)
    params = params_cls() if params_cls is not None else None
    values: dict[str, Any] = {}
    if preset is not None:
        presets = getattr(method, "PRESETS", {})
        if preset not in presets:
            choices = ", ".join(presets) or "none"
            raise ValueError(f"--preset: unknown preset {preset!r} for {method.__name__}; choose from {choices}")
        values.update(presets[preset])
    for key, text in (overrides or {}).items():
        values[key] = text
    config_fields = {f.name for f in dataclasses.fields(config)}
    params_fields = {f.name for f in dataclasses.fields(params)} if params is not None else set()
    config_updates, params_updates = {}, {}
    for key, raw in values.items():
        if key in config_fields:
            target, current, updates = "config", getattr(config, key), config_updates
        elif key in params_fields:
            target, current, updates = "params", getattr(params, key), params_updates
        else:
            known = ", ".join(sorted(config_fields | params_fields))
            raise ValueError(f"--set: unknown key {key!r} for method {method.__name__.split('.')[-1]}; known keys: {known}")
        try:
            updates[key] = _parse_value(raw, current) if isinstance(raw, str) else raw
        except ValueError as err:
            raise ValueError(f"--set {key}={raw}: {err}") from None
        del target
    try:
        if config_updates:
            config = dataclasses.replace(config, **config_updates)
        if params_updates:
            params = dataclasses.replace(params, **params_updates)
    except (ValueError, TypeError) as err:
        raise ValueError(f"--set: {err}") from None
    return config, params
