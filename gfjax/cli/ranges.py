"""The table of every checked option range (`docs/cli.md`): `python -m gfjax.cli.ranges`.

Every registered method's ranges (`Method.ranges`) first, then the other owners of options.
"""
from __future__ import annotations

import dataclasses

from gfjax import methods
from gfjax.cli import _common
from gfjax.dtm.build import DEFAULTS as DTM_DEFAULTS
from gfjax.dtm.build import RANGES as DTM_RANGES
from gfjax.tiling import tiles

# Owners of options other than the methods, in the table's order: (row label, RANGES, defaults, classes).
OTHERS = (
    ("tiling (`--tile-size`, `--buffer`)", tiles.RANGES, {}, (tiles.Tiling,)),
    ("dtm (`--cell`, `--max-edge`)", DTM_RANGES, DTM_DEFAULTS, ()),
    ("commands (tune, train, bench, eval, dtm)", _common.RANGES, _common.DEFAULTS, ()),
)


def markdown_table() -> str:
    """The table of every checked range (`docs/cli.md`): method, key, range, default."""
    lines = ["| method or command | `--set` key or option | valid range | default |", "| --- | --- | --- | --- |"]
    owners = [(m.name, m.ranges, {}, (m.Config, m.Params)) for m in map(methods.get, methods.available())]
    for owner, ranges, given, classes in [*owners, *OTHERS]:
        defaults = dict(given)
        for cls in classes:
            if cls is not None and dataclasses.is_dataclass(cls):
                for field in dataclasses.fields(cls):
                    if field.default is not dataclasses.MISSING:
                        defaults.setdefault(field.name, field.default)
        for key, allowed in ranges.items():
            default = defaults.get(key, "")
            if hasattr(default, "shape"):
                default = default.item()
            shown = f"{default:g}" if isinstance(default, float) else str(default)
            lines.append(f"| {owner} | `{key}` | {allowed.text()} | {shown} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(markdown_table())
