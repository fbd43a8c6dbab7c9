"""docs/ARCHITECTURE.md's layout names every module of the package, so a newcomer finds each."""
from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_the_layout_names_every_module():
    text = (REPO / "docs" / "ARCHITECTURE.md").read_text()
    layout = text[text.index("## Layout"):text.index("## Coordinates")]
    named = set(re.findall(r"[A-Za-z_][A-Za-z0-9_]*\.py", layout))
    cli = re.search(r"one module per subcommand \(([^)]*)\)", layout)
    named |= {f"{name.strip()}.py" for name in cli.group(1).split(",")} if cli else set()
    missing = [str(p.relative_to(REPO)) for p in sorted((REPO / "gfjax").rglob("*.py"))
               if p.name != "__init__.py" and p.name not in named]
    assert missing == [], f"docs/ARCHITECTURE.md's layout does not name {missing}"
