"""`--workers` beyond what the machine holds exits 2 at once, saying the ceiling and why."""
from __future__ import annotations

import os

from cli_helpers import error_line, fake_methods, run_cli, write_scene  # noqa: F401

from gfjax.survey import cluster


def test_a_thousand_workers_exit_2_before_any_is_started(tmp_path, capsys, fake_methods):
    sources = [write_scene(tmp_path / "a.las"), write_scene(tmp_path / "b.las")]
    out = tmp_path / "out"
    out.mkdir()
    code, _, err = run_cli(capsys, "filter", *sources, "-o", out, "--method", "fake", "--workers", "1000")
    line = error_line(err)
    most, _ = cluster.max_local_workers()
    assert code == 2 and f"--workers 1000: at most {most} on this machine" in line and "cores" in line, err
    assert os.listdir(out) == []


def test_the_ceiling_follows_cores_and_the_memory_budget(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setenv("GFJAX_MEMORY_BUDGET_GB", "100")
    assert cluster.max_local_workers()[0] == 2 * cluster.WORKERS_PER_CORE
    monkeypatch.setenv("GFJAX_MEMORY_BUDGET_GB", "3.5")
    most, why = cluster.max_local_workers()
    assert most == 3 and "memory budget of 3.5 GiB" in why
    monkeypatch.setenv("GFJAX_MEMORY_BUDGET_GB", "0.1")
    assert cluster.max_local_workers()[0] == 1
