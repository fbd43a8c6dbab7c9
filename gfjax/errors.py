"""Errors that mean "bad input": the CLI prints them as one line and exits with code 2."""


class InputError(ValueError):
    """A file or an option the user gave is unusable. The message names it and the problem,
    e.g. `InputError("tile.laz: not a LAS/LAZ file (bad signature)")`."""


class SettingError(ValueError):
    """A method's setting (a `Config` or `Params` field) is out of its range, or settings
    disagree, or together ask for more memory than the budget.

    Attributes:
      keys: the fields concerned, the one to change first, e.g. `("window_m", "cell_m")`; a
        caller that knows where each came from (`--set`, `--preset`, a params file) names
        those sources without reading the message.
    """

    def __init__(self, message: str, *keys: str):
        super().__init__(message)
        self.keys = keys
