"""Errors that mean "bad input": the CLI prints them as one line and exits with code 2."""


class InputError(ValueError):
    """A file or an option the user gave is unusable. The message names it and the problem,
    e.g. `InputError("tile.laz: not a LAS/LAZ file (bad signature)")`."""
