"""Kill safety: SIGTERM and SIGHUP end `gfjax filter` like Ctrl-C (no temporary or partial
file, one line, exit 128 + signal); temporary names match no input pattern; stale
temporaries of killed runs are never inputs and are cleaned up."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
from cli_helpers import error_line, fake_methods, no_compilation_cache, run_cli, write_scene  # noqa: F401
from job_helpers import start_program, wait_for_line

from gfjax.errors import InputError
from gfjax.io import atomic
from gfjax.io import las as las_io


def _names(folder: Path) -> list[str]:
    return sorted(os.listdir(folder))


def _stderr_lines(process: subprocess.Popen) -> list[str]:
    return [line for line in process.stderr.read().splitlines() if line.startswith("gfjax:")]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_signal_during_write_leaves_no_temporary_or_partial_output(tmp_path, sig):
    source = write_scene(tmp_path / "in.las")
    with start_program("filter", source, "-o", tmp_path / "out.laz", "--method", "fake", slow_write_from=1) as process:
        try:
            wait_for_line(process, "WRITING", lines=[])
            assert any(atomic.TMP_MARK in name for name in _names(tmp_path))      # the write is under way
            process.send_signal(sig)
            assert process.wait(timeout=60) == 128 + sig
        finally:
            process.kill()
        assert _stderr_lines(process) == [f"gfjax: interrupted by {sig.name}; no partial output left"]
    assert _names(tmp_path) == ["in.las"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP], ids=["SIGINT", "SIGTERM", "SIGHUP"])
def test_a_signal_wrapped_by_a_library_still_exits_with_the_signal(tmp_path, capsys, fake_methods, sig):
    """lazrs turns an exception raised while it calls back into Python (the interruption, when
    a signal lands in its write) into an error of its own ("Failed to call write"): the run
    still ends with 128 + the signal and its one line, not as an internal error."""
    def write(*args, **kwargs):
        try:
            os.kill(os.getpid(), sig)                 # the handler raises here, inside the "library"
            time.sleep(5)
        except BaseException as err:                  # noqa: BLE001 (what lazrs does with it)
            raise RuntimeError("Failed to call write") from err

    source = write_scene(tmp_path / "in.las")
    las_io._write_las, real = write, las_io._write_las
    try:
        code, _, err = run_cli(capsys, "filter", source, "-o", tmp_path / "out.laz", "--method", "fake")
    finally:
        las_io._write_las = real
    assert code == 128 + sig
    assert [line for line in err.splitlines() if line.startswith("gfjax:")] == \
        [f"gfjax: interrupted by {sig.name}; no partial output left"]
    assert _names(tmp_path) == ["in.las"]


def test_sigterm_during_a_multi_file_run_keeps_completed_outputs_and_prints_a_summary(tmp_path):
    source, out = tmp_path / "in", tmp_path / "out"
    source.mkdir()
    out.mkdir()
    for name in ("a.las", "b.las", "c.las"):
        write_scene(source / name)
    with start_program("filter", source, "-o", out, "--method", "fake", "--independent", slow_write_from=2) as process:
        try:
            wait_for_line(process, "WRITING", lines=[])
            process.send_signal(signal.SIGTERM)
            assert process.wait(timeout=60) == 128 + signal.SIGTERM
        finally:
            process.kill()
        lines = _stderr_lines(process)
    assert lines == [f"gfjax: 1 of 3 files done; interrupted: {source / 'b.las'}; not started: {source / 'c.las'}",
                     "gfjax: interrupted by SIGTERM; no partial output left"]
    assert _names(out) == ["a.las"]


def test_temporary_names_match_no_input_pattern(tmp_path):
    for target in ("out.laz", "out.LAS", "dtm.tif", "x" * 250 + ".laz"):
        tmp = atomic.temporary_name(tmp_path / target)
        assert tmp.parent == tmp_path and tmp.name.startswith(".")
        assert tmp.suffix.lower() not in las_io.LAS_SUFFIXES + (".tif", ".tiff")
        assert len(tmp.name) < 200 and atomic.is_temporary(tmp)


def test_temporaries_in_an_input_folder_or_glob_are_not_inputs(tmp_path):
    write_scene(tmp_path / "a.las")
    (tmp_path / f".b.laz{atomic.TMP_MARK}otherhost-123-0123abcd").write_bytes(b"LASF")
    (tmp_path / ".c.0123abcd.tmp.laz").write_bytes(b"LASF")           # the older temporary pattern
    assert las_io.expand_inputs([tmp_path]) == [tmp_path / "a.las"]
    assert las_io.expand_inputs([str(tmp_path / "*.la[sz]")]) == [tmp_path / "a.las"]
    with pytest.raises(InputError, match="no .las/.laz file matches"):
        las_io.expand_inputs([str(tmp_path / ".*")])


def test_a_temporary_named_as_input_exits_2(tmp_path, capsys, fake_methods):
    stale = tmp_path / ".c.0123abcd.tmp.laz"
    stale.write_bytes(b"LASF")
    code, _, err = run_cli(capsys, "filter", stale, "-o", tmp_path / "out.laz", "--method", "fake")
    assert code == 2
    assert "a temporary file of an unfinished gfjax write, not an input" in error_line(err)


def _dead_pid() -> int:
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    return int(done.stdout)


def test_stale_temporary_of_a_dead_process_is_removed_by_the_next_write(tmp_path, capsys, fake_methods):
    write_scene(tmp_path / "in.las")
    stale = tmp_path / f".out.laz{atomic.TMP_MARK}{atomic._host()}-{_dead_pid()}-0123abcd"
    stale.write_bytes(b"half a file")
    code, _, err = run_cli(capsys, "filter", tmp_path, "-o", tmp_path / "out.laz", "--method", "fake")
    assert code == 0, err
    assert _names(tmp_path) == ["in.las", "out.laz"]


def test_temporary_of_a_running_process_is_kept(tmp_path):
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        live = tmp_path / f".out.laz{atomic.TMP_MARK}{atomic._host()}-{sleeper.pid}-0123abcd"
        live.write_bytes(b"being written")
        assert not atomic.is_stale(live)
        assert atomic.remove_stale_temporaries(tmp_path) == [] and live.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_temporary_of_another_host_is_removed_only_by_age(tmp_path):
    other = tmp_path / f".out.laz{atomic.TMP_MARK}otherhost-{os.getpid()}-0123abcd"
    other.write_bytes(b"maybe being written elsewhere")
    assert atomic.remove_stale_temporaries(tmp_path) == [] and other.exists()
    old = time.time() - atomic.STALE_AGE_S - 60
    os.utime(other, (old, old))
    assert atomic.remove_stale_temporaries(tmp_path) == [other] and not other.exists()


def test_files_that_only_look_like_temporaries_are_left_alone(tmp_path):
    keep = [tmp_path / "notes.tmp", tmp_path / "out.laz", tmp_path / f"out{atomic.TMP_MARK}x"]
    for path in keep:
        path.write_bytes(b"user data")
        old = time.time() - 10 * atomic.STALE_AGE_S
        os.utime(path, (old, old))
    assert atomic.remove_stale_temporaries(tmp_path) == []
    assert all(path.exists() for path in keep)


def test_working_folders_of_killed_surveys_are_removed_by_the_next_one(tmp_path, monkeypatch):
    """A survey's stores live in `$TMPDIR/gfjax-survey-<host>-<pid>-*`: SIGKILL leaves them, so
    the next run removes those of processes that are gone, and nothing else."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    host = atomic._host()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    gone = tmp_path / f"gfjax-survey-{host}-{int(dead.stdout)}-abc123"
    alive = tmp_path / f"gfjax-survey-{host}-{os.getppid()}-def456"          # a running process
    other_host = tmp_path / "gfjax-survey-elsewhere-1-ghi789"
    old = tmp_path / "gfjax-survey-elsewhere-2-jkl012"
    for folder in (gone, alive, other_host, old):
        (folder / "catalog").mkdir(parents=True)
        (folder / "catalog" / "0.npy").write_bytes(b"x" * 100)
    os.utime(old, (time.time() - atomic.STALE_AGE_S - 60,) * 2)
    target = tmp_path / "precious"
    target.mkdir()
    (tmp_path / f"gfjax-survey-{host}-{int(dead.stdout)}-link").symlink_to(target)
    with atomic.scratch_folder() as folder:
        assert Path(folder).name.startswith(f"gfjax-survey-{host}-{os.getpid()}-")
        assert not gone.exists() and not old.exists()
        assert alive.exists() and other_host.exists() and target.exists()
    assert not Path(folder).exists()
