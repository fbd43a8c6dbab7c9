"""The command reference of `docs/cli.md`: every subcommand's `--help` as argparse prints it,
at `WIDTH` columns, so the page says what the program does: `python -m gfjax.cli.reference`.
"""
from __future__ import annotations

import contextlib
import io
import os

from gfjax.cli import main

WIDTH = 100        # columns the help is wrapped to (argparse and the method table read COLUMNS)


def help_text(command: str) -> str:
    """`gfjax COMMAND --help`, wrapped at `WIDTH` columns, without trailing spaces."""
    out = io.StringIO()
    before = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(WIDTH)
    try:
        with contextlib.redirect_stdout(out):
            main.main([command, "--help"])
    finally:
        if before is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = before
    return "\n".join(line.rstrip() for line in out.getvalue().strip("\n").splitlines())


def markdown() -> str:
    """One section per subcommand (`main.SUBCOMMANDS`, in help order) holding its help."""
    return "\n\n".join(f"### `gfjax {name}`\n\n```text\n{help_text(name)}\n```" for name in main.SUBCOMMANDS)


if __name__ == "__main__":
    print(markdown())
