"""Reading `params.json`, the thresholds `gfjax tune` fits and `gfjax filter --params` applies.

```json
{"method": "smrf", "gfjax_version": "0.1.0",
 "units": {"slope": "1 (rise over run)", "threshold_m": "m", ...},
 "values": {"slope": 0.17, "threshold_m": 0.45, "scalar": 1.3, "window_m": 18.0},
 "fitted": ["slope", ...], "validation": {...}}
```
`values` holds only keys of the method's `Config`/`Params`; the rest is a report. Writing is
`gfjax.tune.params.write_params`. This module imports no JAX, so the CLI can read the file
before it pays for a method.
"""
from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path
from typing import Any

from gfjax.errors import InputError

MAX_BYTES = 1 << 20  # a params.json of `gfjax tune` takes a few hundred bytes


def read_params(path: str | os.PathLike, *, option: str = "") -> dict[str, Any]:
    """Read and check a params.json; raises `InputError` naming the file (and the option).

    Returns:
      The JSON object; `method` is a string and `values` maps keys to finite numbers.
    """
    path = Path(path)
    where = f"{option} {path}" if option else str(path)
    if os.fspath(path) == "":
        raise InputError(f"{option + ' ' if option else ''}'': empty file name")
    try:
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):  # a FIFO would block the open below
            raise InputError(f"{where}: not a regular file")
        with open(path, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{where}: no such file") from None
    except OSError as err:
        raise InputError(f"{where}: not a readable JSON file ({err.strerror or err})") from None
    if len(raw) > MAX_BYTES:
        raise InputError(f"{where}: larger than {MAX_BYTES} bytes, not a params file of gfjax tune")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{where}: not a readable JSON file ({err})") from None
    except RecursionError:
        raise InputError(f"{where}: JSON nested too deeply") from None
    if not isinstance(data, dict) or not isinstance(data.get("values"), dict):
        raise InputError(f"{where}: expected a JSON object with a 'values' object")
    if not isinstance(data.get("method"), str):
        raise InputError(f"{where}: expected a 'method' name")
    for key, value in data["values"].items():
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(f"{where}: value of {key!r} must be a finite number, got {value!r}")
    return data


__all__ = ["read_params"]
