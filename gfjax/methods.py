"""The registry of ground-filtering methods, and `--set key=value` handling.

Every method package (`gfjax.smrf`, `gfjax.dmf`, ...) exports its `gfjax.method.Method` as
`METHOD`; `PACKAGES` lists them, and every list of names (the CLI's choices, the option
table, the lazy imports of `gfjax`) is derived from it. A package is imported on first use,
so `gfjax info` does not pay for every method. Bad names, keys and values raise `InputError`
naming the option (the CLI exits with code 2).
"""
from __future__ import annotations

import contextlib
import dataclasses
import gc
import importlib
from collections.abc import Mapping
from types import ModuleType
from typing import Any

from gfjax import limits
from gfjax.errors import InputError, SettingError
from gfjax.method import Method

# The method `gfjax filter` runs without `--method`: the soundest across the labelled files with
# its defaults (`experiments/results/corpus_eval.md`; the README says why).
DEFAULT_METHOD = "vote"

# name -> package exporting `METHOD`: the one place a method is registered.
PACKAGES: dict[str, str] = {
    "smrf": "gfjax.smrf",
    "pmf": "gfjax.pmf",
    "csf": "gfjax.csf",
    "dmf": "gfjax.dmf",
    "masf": "gfjax.masf",
    "sparsegf": "gfjax.sparsegf",
    "vote": "gfjax.vote",
}


def names() -> list[str]:
    """Every registered method name, in registry order."""
    return list(PACKAGES)


def available() -> list[str]:
    """Names of the methods whose package imports (a build may leave one out)."""
    out = []
    for name in PACKAGES:
        try:
            get(name)
        except InputError:
            continue
        out.append(name)
    return out


def get(name: str, *, option: str = "--method") -> Method:
    """The `Method` registered as `name` (raises InputError naming `option` and the choices)."""
    if name not in PACKAGES:
        raise InputError(f"{option}: unknown method {name!r}; choose from {', '.join(PACKAGES)}")
    try:
        with collector_paused():
            package = importlib.import_module(PACKAGES[name])
    except ModuleNotFoundError as err:
        if err.name is None or not PACKAGES[name].startswith(err.name):
            raise  # a dependency of an existing method is missing: an internal error
        raise InputError(f"{option}: method {name!r} is not available in this build") from None
    method = getattr(package, "METHOD", None)
    if not isinstance(method, Method):
        raise InputError(f"{option}: method {name!r} is not implemented yet")
    return method


@contextlib.contextmanager
def collector_paused():
    """Python's cyclic garbage collector off inside the block, as it was after.

    Importing a method (JAX, scipy.spatial and the package: some 85,000 new objects the
    collector tracks, next to none of them garbage) otherwise runs it about 200 times over a
    growing heap: a sixth of the import's time.
    """
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def of(method: Method | ModuleType | str) -> Method:
    """`method` as a `Method`: a Method itself, a method package (`gfjax.smrf`) or a name."""
    if isinstance(method, Method):
        return method
    if isinstance(method, str):
        return get(method)
    found = getattr(method, "METHOD", None)
    if not isinstance(found, Method):
        raise TypeError(f"not a method: {method!r} (pass a gfjax.method.Method, a method package or a name)")
    return found


def lattice(method: Method, config: Any, tiling: Any = None) -> Any:
    """The tile lattice a survey runs `method` on tile by tile (`gfjax.tiling.tiles.Lattice`:
    `tiling`, None for its defaults, at `config.cell_m`), for a method whose tiles' labels
    depend on their windows only (`Method.tile_labels`); None for any other method."""
    if not method.tile_labels:
        return None
    from gfjax.tiling.checks import lattice_of

    return lattice_of(tiling, config.cell_m)


def memory_estimates(config: Any, tiling: Any = None) -> list[limits.Estimate]:
    """`config.memory_estimates()` (none when it has no such method), with `tiling` for a
    method that tiles (only those take one)."""
    estimates = getattr(config, "memory_estimates", None)
    if estimates is None:
        return []
    return estimates() if tiling is None else estimates(tiling=tiling)


def _parse_value(text: str, current: Any) -> Any:
    if text.strip().lower() == "none" and not isinstance(current, (bool, str)) and not _is_scalar_array(current):
        return None                  # an optional value; the field's range refuses it where it is not
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


def _as_field_value(value: Any, current: Any) -> Any:
    """A parsed value in the type of the field it replaces (float32 scalar arrays stay so;
    a whole float from a params.json becomes an int for an int field)."""
    if isinstance(current, int) and not isinstance(current, bool) and isinstance(value, float):
        if not value.is_integer():
            raise ValueError(f"expected an integer, got {value}")
        return int(value)
    if _is_scalar_array(current) and not isinstance(current, (bool, int, float)):
        import jax.numpy as jnp

        return jnp.asarray(value, dtype=current.dtype)
    return value


def make_config_and_params(method: Method | ModuleType | str, overrides: Mapping[str, Any] | None = None,
                           preset: str | None = None, *, values: Mapping[str, float] | None = None,
                           values_source: str = "--params", base_config: Any = None, tiling: Any = None,
                           tiling_sources: Mapping[str, str] | None = None) -> tuple[Any, Any]:
    """Build a method's `Config` and `Params` from a preset, fitted values and `key=value`s.

    Precedence, lowest first: the defaults (or `base_config`, e.g. the settings a SparseGF
    model was trained with), `preset`, `values` (e.g. the `values` of a
    `gfjax tune` params.json, named by `values_source` in errors), then `overrides`
    (`--set`). `method`: a `Method`, its package or its name. `tiling`, a `gfjax.Tiling`
    for a method that tiles (`Method.tiles`), joins the checks
    of the rasters the values set (its core must hold a cell; `tiling_sources` names the
    option that gave each of its fields). Keys are matched against the fields of `Config` and of `Params`. An
    unknown key, an unknown preset, a value that does not parse or that the method's own
    checks reject (`Config.__post_init__`: ranges and memory budget, `gfjax.limits`;
    `Params.check()` when it exists) raises `InputError` naming the option and the key.
    """
    method = of(method)
    config = method.Config() if base_config is None else base_config
    params = method.Params() if method.Params is not None else None
    method_name = method.name
    layers: list[tuple[str, Mapping[str, Any]]] = []
    if preset is not None:
        presets = method.presets
        if preset not in presets:
            choices = ", ".join(presets) or "none"
            raise InputError(f"--preset: unknown preset {preset!r} for {method_name}; choose from {choices}")
        layers.append((f"--preset {preset}", presets[preset]))
    layers.append((values_source, values or {}))
    layers.append(("--set", overrides or {}))
    config_fields = {f.name for f in dataclasses.fields(config)}
    params_fields = {f.name for f in dataclasses.fields(params)} if params is not None else set()
    config_updates: dict[str, Any] = {}
    params_updates: dict[str, Any] = {}
    source_of: dict[str, str] = {}
    for source, layer in layers:
        for key, raw in layer.items():
            if key in config_fields:
                current, updates = getattr(config, key), config_updates
            elif key in params_fields:
                current, updates = getattr(params, key), params_updates
            elif key in ("tile_size_m", "buffer_m"):
                raise InputError(f"{source}: {key} is a tiling option, not a setting of method {method_name}: "
                                 "give --tile-size / --buffer (in Python: `tiling=gfjax.Tiling(...)`)")
            else:
                known = ", ".join(sorted(config_fields | params_fields))
                raise InputError(f"{source}: unknown key {key!r} for method {method_name}; known keys: {known}")
            try:
                value = _parse_value(raw, current) if isinstance(raw, str) else raw
            except ValueError as err:
                raise InputError(f"{source} {key}={raw}: {err}") from None
            if key in method.ranges and _is_scalar_array(current) and isinstance(value, (int, float)):
                try:                                      # before the float32 cast can overflow
                    limits.check_value(key, value, method.ranges[key])
                except ValueError as err:
                    raise InputError(f"{source}: {err}") from None
            try:
                updates[key] = _as_field_value(value, current)
            except ValueError as err:
                raise InputError(f"{source} {key}={raw}: {err}") from None
            source_of[key] = source
    try:
        if config_updates:
            config = dataclasses.replace(config, **config_updates)
        if params_updates:
            params = dataclasses.replace(params, **params_updates)
        if params is not None and hasattr(params, "check"):
            params.check()
        if tiling is not None and hasattr(config, "cell_m"):
            tiling.lattice(config.cell_m)
        limits.check_memory(memory_estimates(config, tiling))   # the rasters and loops the values set fit the budget
    except (ValueError, TypeError) as err:
        # the options that gave the keys concerned, the key to change first first; a key left
        # at its default (or a check that names no key) points at every option given, or at
        # --set when none was
        keys = err.keys if isinstance(err, SettingError) else ()
        source_of.update(tiling_sources or {})
        sources = list(dict.fromkeys(source_of[k] for k in keys if k in source_of))
        if not sources:
            sources = ["--set"] if not source_of else sorted(set(source_of.values()))
        raise InputError(f"{', '.join(sources)}: {err}") from None
    return config, params
