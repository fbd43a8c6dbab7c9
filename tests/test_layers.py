"""The package's layers: a method's stages are pure array functions (no files, tiles or caches)."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "gfjax"
STAGES = sorted(PACKAGE.glob("*/stages.py"))
ALLOWED = ("gfjax._types", "gfjax.raster", "gfjax.errors", "gfjax.limits", "gfjax.params")


def gfjax_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("gfjax"):
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names if node.module == "gfjax")
        elif isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names if alias.name.startswith("gfjax"))
    return names


def test_every_method_with_stages_is_checked():
    assert {p.parent.name for p in STAGES} >= {"smrf", "pmf", "dmf", "csf"}


@pytest.mark.parametrize("path", STAGES, ids=[p.parent.name for p in STAGES])
def test_stages_import_only_raster_types_and_their_own_config(path):
    own = f"gfjax.{path.parent.name}"
    foreign = sorted(name for name in gfjax_imports(path)
                     if not name.startswith(ALLOWED) and not name.startswith(f"{own}.config"))
    assert foreign == [], f"{path.relative_to(PACKAGE.parent)} imports {foreign}"
