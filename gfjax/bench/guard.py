"""A guard against speed regressions: whole processes timed as ratios to a peer in the same run.

Machines are shared and noisy, so a case never compares seconds with the seconds of another
day. It times its subject and its peer in alternated pairs (subject, peer, subject, ...),
takes the ratio of their medians, and compares that ratio with the one recorded when the
target was met: more than `TOLERANCE` above it fails. A failing case is timed once more and
judged on all its pairs, so a busy moment alone does not fail it, and a real slowdown still
does. `slowed` injects a slowdown into a subject (`make bench` is tested with one).

Each side is a command: its time is the process's wall time, or, for a side that reports one
(a peer package's filter call, `peer`), the `seconds` of the JSON
object on its last line of output. Knows nothing of data files: the cases are the caller's
(`experiments/bench_guard.py`).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from typing import NamedTuple

from gfjax.bench.harness import Stopwatch

TOLERANCE = 0.15       # a ratio at most this much above the recorded one passes
PAIRS = 5              # alternated pairs timed for a case (and as many again for a failing one)


class GuardError(RuntimeError):
    """A side's command failed: the guard cannot judge its case."""


class Side(NamedTuple):
    """One side of a case.

    Attributes:
      command: argv of the process.
      reported: the process prints a JSON object with `seconds` on its last line, and that is
        its time (else the wall time of the whole process).
      fresh_cache: run with an empty cache folder of its own (`XDG_CACHE_HOME`): a first run.
    """

    command: tuple[str, ...]
    reported: bool = False
    fresh_cache: bool = False


class Case(NamedTuple):
    """A ratio to keep: `subject`'s time over `peer`'s, lower is better."""

    name: str
    subject: Side
    peer: Side
    describes: str = ""


def slowed(side: Side, factor: float) -> Side:
    """`side` run through `python -m gfjax.bench.guard slowed FACTOR -- COMMAND`: the command,
    then a pause of `(factor - 1)` times its own time, so it takes `factor` times as long."""
    return side._replace(command=(sys.executable, "-m", "gfjax.bench.guard", "slowed", repr(float(factor)),
                                  str(int(side.reported)), "--", *side.command))


def time_side(side: Side) -> float:
    """Seconds of one run of `side` (see `Side`).

    Raises:
      GuardError: the command exited non-zero, or reported no seconds.
    """
    env = dict(os.environ)
    with tempfile.TemporaryDirectory(prefix="gfjax-guard-") as scratch:
        if side.fresh_cache:
            env["XDG_CACHE_HOME"] = scratch
            env.pop("GFJAX_EXPORT_CACHE", None)
            env.pop("JAX_COMPILATION_CACHE_DIR", None)
        with Stopwatch() as watch:
            done = subprocess.run(side.command, env=env, capture_output=True, text=True)
        wall = watch.wall_s
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        raise GuardError(f"{' '.join(side.command)}: exit {done.returncode}: {' | '.join(tail)}")
    if not side.reported:
        return wall
    try:
        return float(json.loads(done.stdout.strip().splitlines()[-1])["seconds"])
    except (IndexError, ValueError, KeyError, TypeError) as error:
        raise GuardError(f"{' '.join(side.command)}: no JSON line with 'seconds' at the end of its output") from error


def time_pairs(case: Case, pairs: int, *, warmup: int = 1, clock: Callable[[Side], float] = time_side):
    """`(subject seconds, peer seconds)`: `pairs` alternated runs of each, after `warmup`
    untimed ones of each (caches filled, files in the page cache)."""
    for _ in range(warmup):
        clock(case.subject), clock(case.peer)
    subject, peer = [], []
    for _ in range(pairs):
        subject.append(clock(case.subject))
        peer.append(clock(case.peer))
    return subject, peer


def ratio(subject: Sequence[float], peer: Sequence[float]) -> float:
    """Median of the subject's times over the median of the peer's."""
    return statistics.median(subject) / statistics.median(peer)


def passes(measured: float, recorded: float, tolerance: float = TOLERANCE) -> bool:
    """A measured ratio within `tolerance` of the recorded one (or below it)."""
    return measured <= recorded * (1.0 + tolerance)


def check(cases: Sequence[Case], recorded: Mapping[str, float], *, pairs: int = PAIRS, warmup: int = 1,
          tolerance: float = TOLERANCE, clock: Callable[[Side], float] = time_side,
          report: Callable[[dict], None] = lambda row: None) -> list[dict]:
    """Time every case and judge it against its recorded ratio (a case without one is timed
    and not judged: `passed` None). Returns one row a case: `name`, `ratio`, `recorded`,
    `limit`, `passed`, `subject_s`, `peer_s` (medians) and `pairs`; `report` sees each row
    as it is made."""
    rows = []
    for case in cases:
        subject, peer = time_pairs(case, pairs, warmup=warmup, clock=clock)
        before = recorded.get(case.name)
        if before is not None and not passes(ratio(subject, peer), before, tolerance):
            more = time_pairs(case, pairs, warmup=0, clock=clock)
            subject, peer = subject + more[0], peer + more[1]
        measured = ratio(subject, peer)
        row = {"name": case.name, "describes": case.describes, "ratio": measured, "recorded": before,
               "limit": None if before is None else before * (1.0 + tolerance),
               "passed": None if before is None else passes(measured, before, tolerance),
               "subject_s": statistics.median(subject), "peer_s": statistics.median(peer), "pairs": len(subject)}
        report(row)
        rows.append(row)
    return rows


def _slowed_main(argv: Sequence[str]) -> int:
    """`slowed FACTOR REPORTED -- COMMAND...`: see `slowed`."""
    factor, reported, command = float(argv[0]), argv[1] == "1", list(argv[3:])
    with Stopwatch() as watch:
        done = subprocess.run(command, capture_output=reported, text=True)
    elapsed = watch.wall_s
    if done.returncode != 0:
        return done.returncode
    if reported:
        lines = done.stdout.strip().splitlines()
        seconds = float(json.loads(lines[-1])["seconds"])
        time.sleep((factor - 1.0) * seconds)
        print(json.dumps({"seconds": factor * seconds}))
    else:
        time.sleep((factor - 1.0) * elapsed)
    return 0


def peer(name: str, path: str) -> Side:
    """The side that reads `path` and times one call of peer package `name` on its points
    (`gfjax.bench.peers`; the read is not timed)."""
    return Side((sys.executable, "-m", "gfjax.bench.guard", "peer", name, str(path)), reported=True)


def _peer_main(argv: Sequence[str]) -> int:
    """`peer NAME FILE`: see `peer`; prints `{"seconds": ..., "ground": ...}` last."""
    import numpy as np

    import gfjax
    from gfjax.bench.peers import PEERS

    name, path = argv
    xyz_m = np.ascontiguousarray(gfjax.read(path).xyz_m, np.float64)
    with Stopwatch() as watch:
        ground = PEERS[name].run(xyz_m)
    print(json.dumps({"seconds": watch.wall_s, "ground": int(ground.sum())}))
    return 0


_USAGE = ("usage: python -m gfjax.bench.guard slowed FACTOR REPORTED -- COMMAND...\n"
          "       python -m gfjax.bench.guard peer NAME FILE")

if __name__ == "__main__":
    commands = {"slowed": _slowed_main, "peer": _peer_main}
    if len(sys.argv) < 3 or sys.argv[1] not in commands:
        raise SystemExit(_USAGE)
    raise SystemExit(commands[sys.argv[1]](sys.argv[2:]))
