"""Fuzzing what answers at `--scheduler`: a loopback peer that takes the connection and sends
bytes no Dask scheduler sends. Whatever it sends, and however slowly, `cluster.client` ends in
an `InputError` naming the address (exit 2) within the connect time (`cluster.CONNECT_S`,
shortened here); never another exception, never a hang.

Each connection (`Client` opens two: its identity call and its stream) gets the case's script:
random bytes; messages framed as Dask's TCP comm frames them, holding msgpack of any shape, a
handshake of wrong values, or a near miss of the scheduler's replies; frame headers with huge
lengths or frame counts; a message cut short. Then the peer closes, resets or holds the
connection; or it sends the whole script a byte at a time.
"""
from __future__ import annotations

import contextlib
import socket
import struct
import sys
import threading
import time

import pytest

distributed = pytest.importorskip("distributed")
from distributed.protocol import dumps  # noqa: E402
from fuzz_deadline import Hang, deadline  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from gfjax.errors import InputError  # noqa: E402
from gfjax.survey import cluster  # noqa: E402

CONNECT_S = 1.0                   # the connect time in these tests [s]
TRICKLE_S = 0.02                  # between the bytes of a trickled script [s]


def framed(*frames: bytes) -> bytes:
    """Frames as Dask's TCP comm writes them: their total bytes, their count, each one's bytes
    (uint64 each), then the frames."""
    prelude = struct.pack(f"<Q{len(frames)}Q", len(frames), *map(len, frames))
    return struct.pack("<Q", len(prelude) + sum(map(len, frames))) + prelude + b"".join(frames)


def message(value) -> bytes:
    """`value` as a Dask peer sends it (msgpack, in frames)."""
    return framed(*(bytes(f) for f in dumps(value)))


HANDSHAKE = {"compression": None, "python": tuple(sys.version_info)[:3], "pickle-protocol": 5}
msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1) | st.floats() | st.text(max_size=8)
    | st.binary(max_size=8),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3),
    max_leaves=6)
handshakes = st.fixed_dictionaries({}, optional={
    "compression": st.sampled_from([None, "lz4", "zstd", "snappy", "nope", 1]),
    "python": st.sampled_from([(3, 11, 0), (2, 7, 18), (), "3.11", None]),
    "pickle-protocol": st.sampled_from([-1, 0, 2, 5, 6, 99, "5", None]),
    "extra": msgpack_values})
# near misses of what a scheduler replies: its stream start, identity, an error
replies = st.sampled_from([
    [{"op": "stream-start", "error": "an error"}], [{"op": "stream-stop"}], {"op": "stream-start"}, [], [{}],
    [{"op": "stream-start"}, {"op": "stream-start"}], [{"op": 1}], ["stream-start"],
    {"status": "error", "exception": "x", "traceback": None}, {"status": "OK"}, {"type": "Scheduler", "workers": 1},
    {"type": "Scheduler", "id": "s", "workers": {"w": None}}])
_huge = st.sampled_from([0, 1, 7, 8, 2**31, 2**32 - 1, 2**62, 2**63, 2**64 - 1])
# a part of a script, as ("bytes", raw), ("message", value) or ("cut", value, fraction kept):
# Dask's `dumps` draws from `random`, which a strategy must not, so the bytes are made in the test
parts = st.one_of(
    st.tuples(st.just("bytes"), st.binary(min_size=1, max_size=64)),
    st.tuples(st.just("message"), msgpack_values | handshakes | st.just(HANDSHAKE) | replies),
    st.tuples(st.just("bytes"), st.tuples(_huge, _huge, st.lists(_huge, max_size=3), st.binary(max_size=16)).map(
        lambda h: struct.pack(f"<QQ{len(h[2])}Q", h[0], h[1], *h[2]) + h[3])),      # a frame header: total, count, sizes
    st.tuples(st.just("cut"), msgpack_values | replies, st.floats(0, 1)))


def as_bytes(part) -> bytes:
    kind, value, *kept = part
    if kind == "bytes":
        return value
    data = message(value)
    return data if kind == "message" else data[:int(kept[0] * len(data))]


ENDS = ["close", "reset", "hold", "trickle"]


@contextlib.contextmanager
def peer(script: list[bytes], end: str):
    """A loopback TCP peer that sends `script` on each connection it takes, then ends it as
    `end` says; its address ("tcp://127.0.0.1:port")."""
    stop = threading.Event()
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(8)
        server.settimeout(0.05)

        def answer(connection: socket.socket) -> None:
            with contextlib.suppress(OSError), connection:
                if end == "trickle":
                    for byte in b"".join(script):
                        if stop.wait(TRICKLE_S):
                            return
                        connection.sendall(bytes([byte]))
                else:
                    for part in script:
                        connection.sendall(part)
                if end == "reset":       # RST, not FIN
                    connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                elif end != "close":
                    stop.wait()

        def serve() -> None:
            while not stop.is_set():
                try:
                    connection, _ = server.accept()
                except OSError:          # the timeout, or the socket closed
                    continue
                threading.Thread(target=answer, args=(connection,), daemon=True).start()

        threading.Thread(target=serve, daemon=True).start()
        try:
            yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
        finally:
            stop.set()


@pytest.fixture
def short_connect(monkeypatch):
    """`CONNECT_S` for gfjax's bound, and Dask's own connect timeout a little longer (so a
    connection attempt left behind by a case gives up soon after)."""
    import dask

    monkeypatch.setattr(cluster, "CONNECT_S", CONNECT_S)
    with dask.config.set({"distributed.comm.timeouts.connect": f"{2 * CONNECT_S:g}s"}):
        yield


# A connection attempt that `cluster.client` gave up on runs on in its daemon thread until Dask's
# own timeout, and Dask's retries draw their backoff from `random` while hypothesis draws the
# next case, which hypothesis reports as the strategies using `random` (they do not).
@pytest.mark.filterwarnings("ignore:Do not use the `random` module inside strategies")
@settings(max_examples=25, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(script=st.lists(parts, max_size=4), end=st.sampled_from(ENDS))
def test_a_peer_that_is_no_scheduler_is_bad_input_within_the_connect_time(short_connect, script, end):
    with peer([as_bytes(part) for part in script], end) as address:
        start = time.monotonic()
        try:
            with deadline(CONNECT_S + 4.0), pytest.raises(InputError) as refused:
                with cluster.client(scheduler=address):
                    pass
        except Hang as hang:
            raise AssertionError(f"{address}: {hang}") from None
        took = time.monotonic() - start
    said = str(refused.value)
    assert said.startswith(f"--scheduler {address}: ") and "\n" not in said, said
    assert "not a Dask scheduler address" not in said, said        # it is one: what answers is no scheduler
    assert took < CONNECT_S + 2.0, (took, said)
