"""A survey's tiles as tasks on a Dask cluster (`dask.distributed`).

The catalog's index is a task per file; each filtering task then reads what it needs from the
catalog's stores (or a COPC file's nodes), in a folder every worker reaches (a local cluster
shares this machine's; a remote one needs the folder on shared storage, e.g. `TMPDIR` on a
network file system), and returns one tile's core labels, or one file's labels for a method
that does not tile (CSF's survey that fits in memory: one task labels the whole survey, and a
task per file takes its part). The command waits for the tasks that a file needs, then writes that file
as one process does (`gfjax.survey.Runner`); on a remote cluster the file's copy is a task too
(`Runner.write`), renamed into place by the command.

A task is a pure function of its arguments, so a worker that dies mid-task has its task run
again by Dask (on another or a restarted worker) with the same result. Each worker compiles
a program once and keeps it in the persistent caches (`gfjax.cache`), like any process.
"""
from __future__ import annotations

import concurrent.futures
import contextlib
import logging
import os
import re
import threading
from collections.abc import Callable, Iterator
from typing import Any

from gfjax import heap, limits
from gfjax.errors import InputError

WORKERS_ENV = "GFJAX_WORKERS"        # set in a local cluster's workers: how many share this machine's cores
# A local worker process: Python, JAX and a tile's arrays, about 1 GiB at the default tile [bytes]
# (an estimate, not a measurement); and at most this many workers per core (one task each).
WORKER_BYTES = 1 << 30
WORKERS_PER_CORE = 4


def max_local_workers() -> tuple[int, str]:
    """The most workers a local cluster may start here, and why: `WORKERS_PER_CORE` per core this
    process may run on, and no more than the memory budget (`gfjax.limits`) holds at
    `WORKER_BYTES` each; at least 1."""
    cores = limits.processors()
    budget = limits.memory_budget_bytes()
    most = max(1, min(WORKERS_PER_CORE * cores, int(budget // WORKER_BYTES)))
    return most, (f"{cores} cores at most {WORKERS_PER_CORE} workers each, a memory budget of "
                  f"{budget / 2**30:.1f} GiB at about {WORKER_BYTES / 2**30:.0f} GiB a worker")


# Points of a survey per local worker, at least, for the worker to pay for itself. A local
# cluster starts its workers in a few seconds (a 4-file survey: 6.3-7.3 s on 2 workers, 2.0-3.6 s
# in one process), and 2 workers on 2 cores filter about 1.25x as fast as one process (36 copies
# of bcts_2, 30 M points: 80 s against 103 s, experiments/results/dask_scale.md): sharing gains
# a fifth of the filtering time, which passes a few seconds at about 6 M points (0.3 M points/s).
MIN_POINTS_PER_WORKER = 3_000_000


def local_workers(asked: int | str, points: int) -> tuple[int, str | None]:
    """Workers of a local cluster for a survey of `points` points (from the headers), and the
    line to say when that is not what was asked (None when it is).

    `asked` is a count (`--workers N`: at most `max_local_workers`) or "auto" (one a core, as
    many as the memory budget holds). Either way no more than one worker per
    `MIN_POINTS_PER_WORKER` points; 0 (filter in this process, no cluster) when that leaves one
    worker where more were asked, or none.

    Raises:
      InputError: more workers asked than `max_local_workers`.
    """
    most, why = max_local_workers()
    if asked == "auto":
        wanted = max(1, min(limits.processors(), most))
    else:
        if asked > most:
            raise InputError(f"--workers {asked}: at most {most} on this machine ({why})")
        wanted = asked
    pays = points // MIN_POINTS_PER_WORKER
    workers = min(wanted, pays)
    if workers < 2 and (wanted >= 2 or workers == 0):
        return 0, (f"--workers {asked}: {points:,} points are too few for a cluster to pay for its start "
                   f"(about {MIN_POINTS_PER_WORKER:,} points a worker); filtering in this process")
    if workers < wanted or asked == "auto":
        return workers, f"--workers {asked}: {workers} workers for {points:,} points"
    return workers, None


def available() -> None:
    """Raise `InputError` when `dask.distributed` is not installed (pip install 'gfjax[dask]')."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise InputError("--workers/--scheduler need dask.distributed: pip install 'gfjax[dask]'") from None


CONNECT_S = 45.0     # a scheduler answers within distributed's 30 s connect timeout, or never


def _connect(client_type, scheduler: str):
    """`client_type(scheduler)`, or TimeoutError after `CONNECT_S`: a peer that accepts the
    connection and never answers its handshake holds `Client` forever, whatever its
    `timeout`. The attempt runs in a daemon thread, left behind if it never returns.

    A `Client` that fails to connect (or connects after the caller gave up) is closed in that
    thread, not left to the garbage collector: its `__del__` stops Dask's loop runner under
    the lock that `LoopRunner.start` holds, so a collection that runs inside `start` (any
    thread starting a `Client` or `LocalCluster`) deadlocks there, and every later one with it.
    """
    done: dict = {}
    finished, abandoned = threading.Event(), threading.Event()

    def attempt():
        made = client_type.__new__(client_type)          # held before __init__ can fail
        try:
            made.__init__(scheduler)
        except BaseException as err:             # noqa: BLE001 (handed to the caller's thread)
            done["error"] = err
            finished.set()
            with contextlib.suppress(Exception):
                made.close()
            return
        done["client"] = made
        finished.set()
        if abandoned.is_set():
            with contextlib.suppress(Exception):
                made.close()

    thread = threading.Thread(target=attempt, name="gfjax-scheduler-connect", daemon=True)
    thread.start()
    if not finished.wait(CONNECT_S):
        abandoned.set()
        if not finished.is_set():
            raise TimeoutError(f"nothing answered within {CONNECT_S:g} s")
    if "error" in done:
        raise done["error"]
    return done["client"]


@contextlib.contextmanager
def client(workers: int | None = None, scheduler: str | None = None) -> Iterator:
    """A `dask.distributed.Client`: on a new local cluster of `workers` processes on the
    loopback interface, or on the existing cluster at `scheduler` ("tcp://host:8786").

    A local cluster's workers run one task at a time and split this machine's cores between
    them (`dask_setup`), so N workers do not each start a thread pool over every core.

    Raises:
      InputError: dask.distributed missing, more `workers` than `max_local_workers`, or no
        scheduler answering at `scheduler`.
    """
    if workers is not None:
        most, why = max_local_workers()
        if workers > most:
            raise InputError(f"--workers {workers}: at most {most} on this machine ({why})")
    available()
    from distributed import Client, LocalCluster

    if scheduler is not None:
        port = re.search(r":(\d+)/?$", scheduler)
        if port is not None and not 0 < int(port.group(1)) <= 65535:
            raise InputError(f"--scheduler {scheduler}: port {port.group(1)} is not a TCP port (1-65535)")
        try:                # as Dask reads an address, before connecting: later ValueErrors are the peer's
            from distributed.comm import get_address_host, parse_address, registry

            registry.get_backend(parse_address(scheduler)[0])
            get_address_host(scheduler)
        except ValueError as err:                # not an address ("http://...", "host:")
            raise InputError(f"--scheduler {scheduler}: not a Dask scheduler address ({err}); "
                             "e.g. tcp://host:8786") from None
        try:
            c = _connect(Client, scheduler)
        except (OSError, TimeoutError) as err:
            raise InputError(f"--scheduler {scheduler}: no Dask scheduler answers there ({err})") from None
        except Exception as err:  # noqa: BLE001 (decoding a peer's bytes: a peer that is no scheduler, not a bug)
            raise InputError(f"--scheduler {scheduler}: what answers there is not a Dask scheduler "
                             f"({type(err).__name__}: {err})") from None
        with c:
            yield c
        return
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, scheduler_kwargs={"dashboard_address": ":0"},  # its HTTP server: any free port
                           silence_logs=logging.ERROR, preload=[__name__],
                           env={WORKERS_ENV: str(workers)})
    with cluster, Client(cluster) as c:
        yield c


def result(future, what: str, again: Callable[[], Any] | None = None):
    """`future.result()`; a task whose workers kept dying (Dask's `KilledWorker`, after
    `distributed.scheduler.allowed-failures` tries) becomes a `RuntimeError` naming `what`.
    A task the cluster lost (cancelled, "already forgotten": seen when a worker dies while
    its tasks are rescheduled) is run here by `again` when given (the same pure function:
    the same result)."""
    try:
        return future.result()
    except concurrent.futures.CancelledError:
        if again is None:
            raise
        return again()
    except Exception as err:
        if type(err).__name__ != "KilledWorker":
            raise
        raise RuntimeError(f"{what}: every Dask worker that ran it died (out of memory? killed?); see the "
                           "workers' logs") from None


def dask_setup(worker) -> None:
    """Run by each local worker as it starts (Dask's preload hook), before any task imports
    JAX: its heap set as the `gfjax` program's (`gfjax.heap.tune`), and worker k of N keeps
    cores k, k+N, ... of this machine, so JAX's thread pool (sized from the cores a process
    may use) does not oversubscribe them."""
    heap.tune()
    n = int(os.environ.get(WORKERS_ENV, "0") or 0)
    if n <= 1 or not hasattr(os, "sched_setaffinity"):
        return
    cores = sorted(os.sched_getaffinity(0))
    try:
        k = int(worker.name) % n
    except (TypeError, ValueError):
        return
    mine = cores[k::n]
    if mine:
        os.sched_setaffinity(0, mine)
