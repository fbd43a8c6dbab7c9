"""A survey's tiles as tasks on a real Dask cluster: the same labels as one process, a killed
worker's tile run again, a failing task named."""
from __future__ import annotations

import contextlib
import os
import signal
import sys

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
import cloudpickle  # noqa: E402  (a dependency of distributed)
from test_survey import SMALL_TILES, town, write_grid  # noqa: E402

from gfjax import csf, dmf, smrf, survey  # noqa: E402
from gfjax.cli.main import main  # noqa: E402
from gfjax.errors import InputError  # noqa: E402
from gfjax.io import las as las_io  # noqa: E402
from gfjax.method import Method  # noqa: E402
from gfjax.survey import cluster  # noqa: E402

pytestmark = pytest.mark.slow

# The test's own filters travel to the workers by value (the workers cannot import this file).
cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(autouse=True)
def every_survey_pays_for_a_cluster(monkeypatch):
    """The small surveys here would run in process (`cluster.local_workers`): let them reach the
    cluster, which is what these tests are about."""
    from gfjax.survey import cluster

    monkeypatch.setattr(cluster, "MIN_POINTS_PER_WORKER", 1)


@pytest.fixture(scope="module")
def grid(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cluster")
    xyz, cls = town(seed=3)
    paths, _, _ = write_grid(folder, xyz, cls)
    return paths


@pytest.fixture(scope="module")
def client():
    with cluster.client(workers=2) as c:
        yield c


def labels(paths) -> list[np.ndarray]:
    return [np.asarray(las_io.read(p).classification) for p in paths]


@pytest.fixture(scope="module")
def in_process(grid, tmp_path_factory):
    """Each method's classes of every file of `grid`, filtered as one survey in this process."""
    done = {}

    def classes(method, tiling) -> list[np.ndarray]:
        if method not in done:
            out = tmp_path_factory.mktemp("one")
            done[method] = labels(survey.filter(grid, out, method=method, tiling=tiling))
        return done[method]

    return classes


@pytest.mark.parametrize("method, tiling", [(smrf, SMALL_TILES), (dmf, None), (csf, None)],
                         ids=["smrf", "dmf", "csf (the survey as one cloud)"])
def test_the_cluster_labels_every_file_as_one_process(grid, client, in_process, method, tiling, tmp_path):
    want = in_process(method, tiling)
    (tmp_path / "many").mkdir()
    written = survey.filter(grid, tmp_path / "many", method=method, tiling=tiling, client=client)
    assert [p.name for p in written] == [p.name for p in grid]
    for a, b in zip(labels(written), want):
        np.testing.assert_array_equal(a, b)
    assert any(np.any(a == 2) for a in want) and any(np.any(a != 2) for a in want)


def test_filter_workers_and_scheduler_write_the_single_process_files(grid, client, tmp_path):
    """Each file's copy written by a worker (committed by the command), or, with `--dtm`, by
    the command from the cluster's labels."""
    names = ("one", "workers", "scheduler", "out-of-core", "dtm", "dtms")
    outs = {name: tmp_path / name for name in names}
    for out in outs.values():
        out.mkdir()
    sets = ["--method", "smrf", "--tile-size", "40", "--buffer", "8"]
    address = client.scheduler.address
    cluster_options = {"workers": ["--workers", "2"], "scheduler": ["--scheduler", address],
                       "out-of-core": ["--out-of-core", "--scheduler", address],
                       "dtm": ["--scheduler", address, "--dtm", str(outs["dtms"])]}
    assert main(["filter", *map(str, grid), "-o", str(outs["one"]), *sets]) == 0
    for name, options in cluster_options.items():
        assert main(["filter", *map(str, grid), "-o", str(outs[name]), *options, *sets]) == 0
    assert sorted(p.name for p in outs["dtms"].iterdir()) == sorted(p.with_suffix(".tif").name for p in grid)
    for out in outs.values():
        assert not [p for p in out.iterdir() if p.name.startswith(".")]        # no temporary left
    for path in grid:
        want = las_io.read(outs["one"] / path.name)
        for name in cluster_options:
            got = las_io.read(outs[name] / path.name)
            np.testing.assert_array_equal(got.classification, want.classification, err_msg=name)
            assert np.array_equal(got.las.points.array, want.las.points.array), name


def test_a_survey_run_as_one_cloud_gives_the_workers_dtms_their_halo(grid, tmp_path):
    """CSF's survey as one task on `--workers`, with `--dtm`: each file's part comes back with
    its neighbours' ground points, so the classes and DTMs equal one process's."""
    import rasterio

    runs = {"one": [], "workers": ["--workers", "2"]}
    for name, options in runs.items():
        (tmp_path / name / "dtm").mkdir(parents=True)
        assert main(["filter", *map(str, grid), "-o", str(tmp_path / name), "--method", "csf", "-q",
                     "--dtm", str(tmp_path / name / "dtm"), *options]) == 0
    for path in grid:
        want, got = (las_io.read(tmp_path / name / path.name).classification for name in runs)
        np.testing.assert_array_equal(got, want)
        with rasterio.open(tmp_path / "one" / "dtm" / path.with_suffix(".tif").name) as a, \
                rasterio.open(tmp_path / "workers" / "dtm" / path.with_suffix(".tif").name) as b:
            np.testing.assert_array_equal(a.read(1), b.read(1))


def test_one_file_on_the_cluster_labels_as_in_process(grid, client, tmp_path, monkeypatch):
    """Relative paths too: the workers' working folder is not the command's."""
    sets = ["--method", "smrf", "--tile-size", "40", "--buffer", "8"]
    assert main(["filter", str(grid[0]), "-o", str(tmp_path / "one.laz"), *sets]) == 0
    monkeypatch.chdir(grid[0].parent)
    (tmp_path / "rel").mkdir()
    rel = os.path.relpath(tmp_path / "rel" / "cluster.laz")
    assert main(["filter", grid[0].name, "-o", rel, "--scheduler", client.scheduler.address, *sets]) == 0
    np.testing.assert_array_equal(las_io.read(tmp_path / "rel" / "cluster.laz").classification,
                                  las_io.read(tmp_path / "one.laz").classification)
    assert os.listdir(tmp_path / "rel") == ["cluster.laz"]


def _dies_once(marker: str) -> Method:
    """SMRF, except that the first tile to run kills its worker process (SIGKILL, mid-task)."""

    def filter(points, *, tiling=None, **kwargs):
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            return smrf.filter(points, tiling=tiling, **kwargs)
        os.kill(os.getpid(), signal.SIGKILL)

    return _method("dies_once", filter)


def _method(name: str, filter) -> Method:
    """A method made here: SMRF's settings and rules with `filter`."""
    return Method(name, filter, smrf.Config, smrf.Params, {}, {}, adapt=smrf.adapt,
                  hides_low_outliers=smrf.HIDES_LOW_OUTLIERS, tiles=True, tile_labels=True)


def test_a_killed_worker_has_its_tile_run_again(grid, client, in_process, tmp_path):
    want = in_process(smrf, SMALL_TILES)
    marker = tmp_path / "killed"
    (tmp_path / "many").mkdir()
    written = survey.filter(grid, tmp_path / "many", method=_dies_once(str(marker)), tiling=SMALL_TILES, client=client)
    assert marker.exists()                       # a worker did die mid-task
    for a, b in zip(labels(written), want):
        np.testing.assert_array_equal(a, b)
    client.wait_for_workers(2, timeout=60)        # the nanny restarted it


def _fails_on_tile(bad_key):
    def filter(points, *, tiling=None, **kwargs):
        if points.name == f"survey tile {bad_key}":
            raise InputError(f"{points.name}: a bad tile")
        return smrf.filter(points, tiling=tiling, **kwargs)

    return _method("fails_on_tile", filter)


def test_a_failing_task_is_named_and_nothing_is_written(grid, client, tmp_path):
    with pytest.raises(InputError, match=r"survey tile \(0, 0\): a bad tile"):
        survey.filter(grid, tmp_path, method=_fails_on_tile((0, 0)), tiling=SMALL_TILES, client=client)
    assert not list(tmp_path.glob("*.laz"))           # the first file needs tile (0, 0): none written


@pytest.mark.parametrize("options, message", [
    (["--workers", "0"], "--workers"),
    (["--workers", "two"], "or auto"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "give one"),
    (["--workers", "2", "--independent"], "drop --independent"),
    (["--scheduler", "tcp://127.0.0.1:1"], "no Dask scheduler answers"),
    (["--scheduler", "http://127.0.0.1:8786"], "not a Dask scheduler address"),
], ids=["zero", "not-a-number", "both", "independent", "no-scheduler", "not-an-address"])
def test_bad_cluster_options_are_one_line(grid, tmp_path, capsys, options, message):
    import dask

    with dask.config.set({"distributed.comm.timeouts.connect": "2s"}):
        code = main(["filter", *map(str, grid), "-o", str(tmp_path), *options])
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not list(tmp_path.iterdir())


def test_a_task_the_cluster_lost_is_run_here():
    """A future cancelled under the command ("already forgotten", seen when a worker dies while
    its tasks are rescheduled) is computed here by the same function; other errors still raise."""
    from distributed.client import FutureCancelledError

    class Lost:
        def result(self):
            raise FutureCancelledError("tile_labels-1", "already forgotten")

    assert cluster.result(Lost(), "survey tile (0, 0)", again=lambda: "labels") == "labels"
    with pytest.raises(FutureCancelledError):
        cluster.result(Lost(), "survey tile (0, 0)")


def test_a_peer_that_accepts_and_never_answers_is_refused_after_the_connect_time(monkeypatch):
    """`Client` waits forever on a peer that takes the connection and never sends its
    handshake, whatever its timeout: the connection attempt is bounded here."""
    import socket

    monkeypatch.setattr(cluster, "CONNECT_S", 2.0)
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        address = f"tcp://127.0.0.1:{silent.getsockname()[1]}"
        with pytest.raises(InputError, match=f"--scheduler {address}: no Dask scheduler answers there "
                                             r"\(nothing answered within 2 s\)"):
            with cluster.client(scheduler=address):
                pass


# an empty msgpack map (0x80) as Dask's TCP comm frames a message: total bytes, frame count, frame size
EMPTY_MAP = (17).to_bytes(8, "little") + (1).to_bytes(8, "little") + (1).to_bytes(8, "little") + b"\x80"


@pytest.mark.parametrize("reply, problem", [
    (b"\x01" + bytes(7) + (2**63).to_bytes(8, "little"), ""), (b"HTTP/1.1 200 OK\r\n\r\n", ""),
    (EMPTY_MAP, "what answers there is not a Dask scheduler")], ids=["8-EiB-frame", "http", "empty-handshake"])
def test_a_peer_that_sends_what_no_scheduler_sends_is_bad_input(reply, problem):
    """Found by tests/reliability/test_fuzz_dask_peers.py: a handshake of an empty map makes Dask
    raise ValueError, which was taken for a bad address ("not a Dask scheduler address")."""
    import socket
    import threading

    with socket.socket() as peer:
        peer.bind(("127.0.0.1", 0))
        peer.listen(4)

        def answer():
            with contextlib.suppress(OSError):
                connection, _ = peer.accept()
                with connection:
                    connection.sendall(reply)
                    connection.recv(1)

        threading.Thread(target=answer, daemon=True).start()
        address = f"tcp://127.0.0.1:{peer.getsockname()[1]}"
        with pytest.raises(InputError, match=f"--scheduler {address}: {problem}") as refused:
            with cluster.client(scheduler=address):
                pass
        assert "not a Dask scheduler address" not in str(refused.value)


# A process that fails to connect to a peer (EMPTY_MAP for its handshake), then collects its
# garbage as `LoopRunner.start` would, holding Dask's loop lock.
_COLLECTED_UNDER_THE_LOOP_LOCK = f"""
import contextlib, gc, socket, threading
from distributed.utils import LoopRunner
from gfjax.errors import InputError
from gfjax.survey import cluster

with socket.socket() as peer:
    peer.bind(("127.0.0.1", 0))
    peer.listen(4)

    def answer():
        with contextlib.suppress(OSError):
            while True:
                connection, _ = peer.accept()
                with connection:
                    connection.sendall({EMPTY_MAP!r})

    threading.Thread(target=answer, daemon=True).start()
    with contextlib.suppress(InputError), cluster.client(scheduler=f"tcp://127.0.0.1:{{peer.getsockname()[1]}}"):
        raise SystemExit("connected")
with LoopRunner._lock:
    gc.collect()
print("collected")
"""


def test_a_client_that_fails_to_connect_leaves_no_deadlock_to_the_garbage_collector():
    """Found by tests/reliability/test_fuzz_dask_peers.py, after which the next local cluster
    in the same process hung for ever: a `Client` that failed to connect was left to the garbage
    collector, and its `__del__` stops Dask's loop runner under `LoopRunner._lock`, which
    `LoopRunner.start` holds while it allocates; a collection there deadlocked, and every later
    `Client` or `LocalCluster` waited on the lock. In a subprocess, which a regression hangs."""
    import subprocess

    done = subprocess.run([sys.executable, "-c", _COLLECTED_UNDER_THE_LOOP_LOCK], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode == 0 and done.stdout.strip() == "collected", done.stderr[-2000:]


@pytest.mark.parametrize("asked, points, workers", [
    (2, 1_000, 0), (2, 5_999_999, 0), (2, 6_000_000, 2), (4, 9_000_000, 3), (1, 3_000_000, 1), (1, 2_999_999, 0),
    ("auto", 1_000, 0)])
def test_a_local_cluster_is_only_as_large_as_the_survey_pays_for(monkeypatch, asked, points, workers):
    from gfjax.survey import cluster

    monkeypatch.setattr(cluster, "MIN_POINTS_PER_WORKER", 3_000_000)
    monkeypatch.setattr(cluster, "max_local_workers", lambda: (8, "a test"))
    got, note = cluster.local_workers(asked, points)
    assert got == workers
    assert (note is None) == (got == asked)
    if got == 0:
        assert "too few" in note and "in this process" in note


def test_auto_takes_a_worker_a_core(monkeypatch):
    from gfjax.survey import cluster

    monkeypatch.setattr(cluster, "max_local_workers", lambda: (8, "a test"))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert cluster.local_workers("auto", 10 ** 9) == (3, "--workers auto: 3 workers for 1,000,000,000 points")


def test_workers_on_a_survey_too_small_says_so_and_filters_here(grid, tmp_path, capsys, monkeypatch):
    from gfjax.survey import cluster

    monkeypatch.setattr(cluster, "MIN_POINTS_PER_WORKER", 10 ** 9)
    monkeypatch.setattr(cluster, "client", lambda **kw: pytest.fail("no cluster for a small survey"))
    (tmp_path / "one").mkdir()
    (tmp_path / "asked").mkdir()
    sets = ["--method", "smrf", "--tile-size", "40", "--buffer", "8"]
    assert main(["filter", *map(str, grid), "-o", str(tmp_path / "one"), *sets]) == 0
    capsys.readouterr()
    assert main(["filter", *map(str, grid), "-o", str(tmp_path / "asked"), "--workers", "2", *sets]) == 0
    assert "--workers 2:" in capsys.readouterr().err
    for path in grid:
        np.testing.assert_array_equal(las_io.read(tmp_path / "asked" / path.name).classification,
                                      las_io.read(tmp_path / "one" / path.name).classification)


def test_a_local_worker_starts_with_the_programs_heap_and_its_share_of_the_cores(monkeypatch):
    """`dask_setup` (Dask's preload hook of a local worker): the heap as the `gfjax` program
    sets it, then worker k of N on cores k, k+N, ..."""
    from types import SimpleNamespace

    from gfjax import heap

    done = []
    monkeypatch.setattr(heap, "tune", lambda: done.append("tune"))
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cores: done.append(sorted(cores)), raising=False)
    monkeypatch.setenv(cluster.WORKERS_ENV, "2")
    cluster.dask_setup(SimpleNamespace(name=1))
    assert done == ["tune", [1, 3]]
