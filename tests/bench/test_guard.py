"""The speed regression guard (`make bench`): its judgement, and that it catches an injected
slowdown of a real process while an unchanged one passes."""
from __future__ import annotations

import json
import sys

import pytest

from gfjax.bench import guard

SLEEP = 0.4           # seconds of the stand-in process: long beside a process start, short for a test


def sleeper(seconds: float = SLEEP, *, reported: bool = False) -> guard.Side:
    code = (f"import json, time; time.sleep({seconds})" +
            (f"; print('a line first'); print(json.dumps({{'seconds': {seconds}}}))" if reported else ""))
    return guard.Side((sys.executable, "-c", code), reported=reported)


def test_a_ratio_passes_within_the_tolerance_of_its_record():
    assert guard.passes(1.0, 1.0) and guard.passes(1.149, 1.0) and guard.passes(0.5, 1.0)
    assert not guard.passes(1.151, 1.0)
    assert guard.ratio([1, 2, 9], [1, 1, 1]) == 2.0


def test_a_process_slowed_by_a_fifth_fails_and_the_same_process_passes():
    case = guard.Case("sleep/sleep", sleeper(), sleeper())
    slowed = case._replace(subject=guard.slowed(case.subject, 1.2))
    rows = guard.check([case, slowed], {"sleep/sleep": 1.0}, pairs=3, warmup=0)
    assert rows[0]["passed"] and rows[0]["pairs"] == 3
    assert rows[1]["passed"] is False and rows[1]["pairs"] == 6        # timed again before it failed
    assert rows[1]["ratio"] >= 1.15


def test_a_reported_time_is_read_from_the_last_line_and_slowed_too():
    assert guard.time_side(sleeper(0.01, reported=True)) == pytest.approx(0.01)
    slowed = guard.slowed(sleeper(0.01, reported=True), 1.2)
    assert guard.time_side(slowed) == pytest.approx(0.012)


def test_a_case_without_a_record_is_timed_not_judged():
    clock = iter([2.0, 1.0] * 4).__next__
    row, = guard.check([guard.Case("new", sleeper(), sleeper())], {}, pairs=3, clock=lambda side: clock())
    assert row["passed"] is None and row["ratio"] == 2.0 and row["limit"] is None


def test_a_failing_command_or_a_missing_report_is_a_guard_error():
    with pytest.raises(guard.GuardError, match="exit 3"):
        guard.time_side(guard.Side((sys.executable, "-c", "raise SystemExit(3)")))
    with pytest.raises(guard.GuardError, match="no JSON line"):
        guard.time_side(guard.Side((sys.executable, "-c", "print('done')"), reported=True))


def test_a_fresh_cache_side_runs_with_an_empty_cache_folder_of_its_own(tmp_path):
    out = tmp_path / "seen.json"
    code = f"import os, json; json.dump(os.listdir(os.environ['XDG_CACHE_HOME']), open({str(out)!r}, 'w'))"
    guard.time_side(guard.Side((sys.executable, "-c", code), fresh_cache=True))
    assert json.loads(out.read_text()) == []
