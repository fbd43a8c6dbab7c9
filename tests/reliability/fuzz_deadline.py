"""A time limit for one fuzzed case, which makes a hang a failure instead of a stuck suite."""
from __future__ import annotations

import contextlib
import faulthandler
import signal


class Hang(BaseException):
    """Raised in the main thread when a case passes its time (not an `Exception`: gfjax's own
    `except Exception` around a user's bytes must not turn it into a refusal)."""


@contextlib.contextmanager
def deadline(seconds: float):
    """Raise `Hang` after `seconds` (SIGALRM: in the main thread, between Python bytecodes); a
    hang in native code is cut by faulthandler, which ends the process with every thread's
    traceback, at twice that. Catch `Hang` and raise an `AssertionError`: hypothesis passes a
    `BaseException` on instead of shrinking it."""
    def _raise(*_):
        raise Hang(f"still running after {seconds:g} s")

    previous = signal.signal(signal.SIGALRM, _raise)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    faulthandler.dump_traceback_later(2 * seconds, exit=True)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        faulthandler.cancel_dump_traceback_later()
        signal.signal(signal.SIGALRM, previous)
