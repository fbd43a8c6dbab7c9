"""Fuzz the LAS/LAZ reading path (`gfjax.io.las.read`) with mutated valid files.

    nice -n 10 python experiments/fuzz_reader.py --minutes 10        # writes results/fuzz_reader.md

Hypothesis (binary strategies, generate + target phases; `hypothesis.target` steers towards
inputs that get further through the reader: past the layout checks, past laspy's header, to a
full read) draws a valid seed file (LAS 1.2/1.4, LAZ 1.2/1.4, with and without EVLRs, one LAZ
of two chunks) and mutates it: header fields set to edge values (0, 1, -1, type limits, NaN,
inf, random), random bytes overwritten anywhere (some in the first 1 KiB: header and VLRs),
the file cut short, bytes appended or a slice removed; the 4-byte signature is left alone
(it is checked first, and a run that broke it half the time learnt little).

A case whose header count disagrees with its data is also read with `trust_data=True` (as
`gfjax filter --trust-data` does) and written back. Each case runs in a long-lived worker process (address space capped at 4 GiB, so a huge
allocation fails as MemoryError instead of swapping), which reads the mutated file with
`gfjax.io.las.read`, and on success writes it back with `gfjax.io.las.write` and reads that
again. The outcome the CLI would give is: `InputError` -> exit 2 (expected), success -> exit
0; any other exception -> exit 1 (a finding), no answer within 10 s -> a hang (the worker is
killed and restarted), the worker dying -> a crash. Findings are grouped by exception type and
the innermost frame of the traceback, and one reproducer per group is kept under
`experiments/results/fuzz_reader_cases/`.
"""
from __future__ import annotations

import argparse
import collections
import io
import math
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
HANG_S = 10.0
MEMORY_BYTES = 4 << 30

# (offset, struct format) of the public header block fields (LAS 1.4 layout; 1.2 stops at 227).
FIELDS = {
    "version_major": (24, "<B"), "version_minor": (25, "<B"), "global_encoding": (6, "<H"),
    "header_size": (94, "<H"), "offset_to_points": (96, "<I"), "n_vlrs": (100, "<I"),
    "point_format": (104, "<B"), "record_length": (105, "<H"), "legacy_count": (107, "<I"),
    "scale_x": (131, "<d"), "scale_y": (139, "<d"), "scale_z": (147, "<d"),
    "offset_x": (155, "<d"), "offset_y": (163, "<d"), "offset_z": (171, "<d"),
    "max_x": (179, "<d"), "min_x": (187, "<d"), "max_z": (211, "<d"),
    "start_waveform": (227, "<Q"), "start_evlr": (235, "<Q"), "n_evlrs": (243, "<I"),
    "count_64": (247, "<Q"),
}


# ----------------------------------------------------------------------------- seeds

def make_seeds() -> list[tuple[str, bytes]]:
    """Valid files (suffix, bytes) the mutations start from."""
    import laspy
    import numpy as np
    from laspy.vlrs.vlrlist import VLRList

    def build(version, point_format, n, *, evlr=False, compress=False, crs=False):
        header = laspy.LasHeader(point_format=point_format, version=version)
        header.scales = np.array([0.01, 0.01, 0.01])
        header.offsets = np.array([500_000.0, 5_400_000.0, 0.0])
        if crs:
            import pyproj
            header.add_crs(pyproj.CRS.from_epsg(32632))
        las = laspy.LasData(header)
        rng = np.random.default_rng(n)
        las.x = 500_000.0 + rng.uniform(0, 50, n)
        las.y = 5_400_000.0 + rng.uniform(0, 50, n)
        las.z = rng.uniform(0, 5, n)
        las.classification = rng.choice(np.array([1, 2], np.uint8), n)
        if evlr:
            las.evlrs = VLRList([laspy.VLR(user_id="fuzz", record_id=1, record_data=b"payload" * 4)])
        out = io.BytesIO()
        las.write(out, do_compress=compress)
        return (".laz" if compress else ".las"), out.getvalue()

    return [build("1.2", 3, 200), build("1.4", 6, 200, evlr=True), build("1.2", 1, 300, compress=True, crs=True),
            build("1.4", 6, 300, compress=True, evlr=True), build("1.4", 7, 250, compress=True),
            build("1.2", 0, 50_100, compress=True)]


# ----------------------------------------------------------------------------- worker

def _finding_key(err: BaseException) -> str:
    frames = traceback.extract_tb(err.__traceback__)
    last = frames[-1] if frames else None
    where = f"{Path(last.filename).name}:{last.lineno}" if last else "?"
    return f"{type(err).__name__} at {where}"


def run_case(data: bytes, suffix: str, folder: Path) -> tuple[str, int, str]:
    """(outcome, stage reached, detail); outcome is 'ok', 'input_error' or 'exit1'."""
    from gfjax.errors import InputError
    from gfjax.io import las as las_io
    from gfjax.io import las_layout

    path = folder / f"case{suffix}"
    path.write_bytes(data)
    stage = 0
    try:
        las_layout.check_layout(path)
        stage = 1
        las_io.read_header(path)
        stage = 2
        cloud = las_io.read(path, units="m")
        stage = 3
        out = folder / f"out{suffix}"
        las_io.write(cloud, out)
        again = las_io.read(out, units="m")
        if again.n_points != cloud.n_points:
            raise AssertionError(f"round trip lost points: {cloud.n_points} -> {again.n_points}")
        out.unlink()
        return "ok", 4, ""
    except InputError as err:
        if "--trust-data" not in str(err):
            return "input_error", stage, str(err).split(": ", 1)[-1][:80]
        try:  # the count disagrees: read what the file holds, as `filter --trust-data` does
            cloud = las_io.read(path, units="m", trust_data=True)
            out = folder / f"out{suffix}"
            las_io.write(cloud, out)
            if las_io.read(out, units="m").n_points != cloud.n_points:
                raise AssertionError("round trip lost points") from None
            out.unlink()
            return "ok_trusted", 5, ""
        except InputError as again:
            return "input_error", stage, "(--trust-data) " + str(again).split(": ", 1)[-1][:70]
        except Exception as again:  # noqa: BLE001
            return "exit1", stage, "--trust-data: " + _finding_key(again) + " | " + f"{again}"[:200]
    except Exception as err:  # noqa: BLE001 (what the CLI would turn into exit 1)
        return "exit1", stage, _finding_key(err) + " | " + f"{err}"[:200]


def worker() -> None:
    """Read (suffix, bytes) cases from stdin, answer (outcome, stage, detail) on stdout."""
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_BYTES, MEMORY_BYTES))
    sys.path.insert(0, str(REPO))
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    with tempfile.TemporaryDirectory(prefix="gfjax-fuzz-") as tmp:
        folder = Path(tmp)
        while True:
            head = stdin.read(8)
            if len(head) < 8:
                return
            case = pickle.loads(stdin.read(int.from_bytes(head, "little")))
            answer = pickle.dumps(run_case(case[1], case[0], folder))
            stdout.write(len(answer).to_bytes(8, "little") + answer)
            stdout.flush()


class Worker:
    """A worker process with a per-case time limit; restarted after a hang or a crash."""

    def __init__(self):
        self.proc = None
        self.start()

    def start(self):
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"], bufsize=0,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)

    def stop(self):
        self.proc.kill()
        self.proc.wait()

    def run(self, suffix: str, data: bytes) -> tuple[str, int, str]:
        message = pickle.dumps((suffix, data))
        try:
            self.proc.stdin.write(len(message).to_bytes(8, "little") + message)
            self.proc.stdin.flush()
        except BrokenPipeError:
            code = self.proc.wait()
            self.start()
            return "crash", 0, f"worker died (exit {code})"
        deadline = time.monotonic() + HANG_S
        head = self._read(8, deadline)
        size = int.from_bytes(head, "little") if head is not None and len(head) == 8 else None
        answer = self._read(size, deadline) if size is not None else head
        if answer is None:
            self.stop()
            self.start()
            return "hang", 0, f"no answer within {HANG_S:.0f} s"
        if size is None or len(answer) < size:
            code = self.proc.wait()
            self.start()
            return "crash", 0, f"worker died (exit {code})"
        return pickle.loads(answer)

    def _read(self, size: int, deadline: float) -> bytes | None:
        """`size` bytes from the worker; fewer when it died; None past `deadline`."""
        import select

        fd, chunks, got = self.proc.stdout.fileno(), [], 0
        while got < size:
            ready, _, _ = select.select([fd], [], [], max(deadline - time.monotonic(), 0.0))
            if not ready:
                return None
            chunk = os.read(fd, size - got)
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        return b"".join(chunks)


# ----------------------------------------------------------------------------- mutations

def strategies(seeds):
    from hypothesis import strategies as st

    def field_value(fmt: str):
        if fmt == "<d":
            return st.one_of(st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, math.nan, math.inf, -math.inf,
                                              0.01, 2.0**31]), st.floats(allow_nan=True, allow_infinity=True))
        bits = struct.calcsize(fmt) * 8
        top = 2**bits - 1
        return st.one_of(st.sampled_from([0, 1, 2, top, top - 1, top // 2, top // 2 + 1]),
                         st.integers(0, top))

    field = st.sampled_from(sorted(FIELDS)).flatmap(
        lambda name: st.tuples(st.just("field"), st.just(name), field_value(FIELDS[name][1])))
    header_bytes = st.tuples(st.just("bytes"), st.integers(4, 1023), st.binary(min_size=1, max_size=8))
    any_bytes = st.tuples(st.just("bytes_anywhere"), st.floats(0, 1), st.binary(min_size=1, max_size=16))
    cut = st.tuples(st.just("cut"), st.floats(0, 1), st.just(b""))
    append = st.tuples(st.just("append"), st.just(0), st.binary(min_size=1, max_size=256))
    remove = st.tuples(st.just("remove"), st.floats(0, 1), st.integers(1, 512))
    mutation = st.one_of(field, header_bytes, any_bytes, cut, append, remove)
    return st.tuples(st.integers(0, len(seeds) - 1), st.lists(mutation, min_size=1, max_size=4))


def mutate(data: bytes, mutations) -> bytes:
    out = bytearray(data)
    for kind, where, what in mutations:
        if kind == "field":
            offset, fmt = FIELDS[where]
            if offset + struct.calcsize(fmt) <= len(out):
                struct.pack_into(fmt, out, offset, what)
        elif kind == "bytes":
            out[where:where + len(what)] = what[: max(len(out) - where, 0)] if where < len(out) else b""
        elif kind == "bytes_anywhere" and len(out) > 4:  # the signature is left alone: it is checked first
            at = min(max(int(where * len(out)), 4), len(out) - 1)
            out[at:at + len(what)] = what[: len(out) - at]
        elif kind == "cut":
            del out[max(int(where * len(out)), 4):]
        elif kind == "append":
            out += what
        elif kind == "remove" and out:
            at = max(int(where * len(out)), 4)
            del out[at:at + what]
    return bytes(out)


# ----------------------------------------------------------------------------- main

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--results", type=Path, default=HERE / "results" / "fuzz_reader.md")
    args = parser.parse_args()
    if args.worker:
        worker()
        return
    sys.path.insert(0, str(REPO))
    from hypothesis import HealthCheck, Phase, given, settings, target

    from gfjax.bench.harness import Stopwatch

    seeds = make_seeds()
    cases_dir = args.results.parent / "fuzz_reader_cases"
    stats = collections.Counter()
    stages = collections.Counter()
    messages = collections.Counter()
    findings: dict[str, dict] = {}
    slowest = [0.0, ""]
    work = Worker()
    end = time.monotonic() + 60 * args.minutes        # a deadline; the run's time is `clock`'s
    clock = Stopwatch()

    @settings(max_examples=500, deadline=None, database=None, phases=[Phase.generate, Phase.target],
              suppress_health_check=list(HealthCheck))
    @given(strategies(seeds))
    def one(case):
        if time.monotonic() > end:
            return  # the time is up: let hypothesis finish this run without work
        index, mutations = case
        suffix, seed = seeds[index]
        data = mutate(seed, mutations)
        with Stopwatch() as watch:
            outcome, stage, detail = work.run(suffix, data)
        took = watch.wall_s
        if took > slowest[0]:
            slowest[:] = [took, f"{outcome}: {detail}"]
        stats[outcome] += 1
        stages[stage] += 1
        target(float(stage), label="stage reached")
        if outcome == "input_error":
            messages[detail.replace("(--trust-data) ", "--trust-data: ").split(" (")[0].strip()[:60]] += 1
        if outcome in ("exit1", "hang", "crash"):
            key = f"{outcome}: {detail.split(' | ')[0]}"
            if key not in findings:
                cases_dir.mkdir(parents=True, exist_ok=True)
                name = cases_dir / f"finding{len(findings):03d}{suffix}"
                name.write_bytes(data)
                findings[key] = {"count": 0, "example": detail, "file": name.name}
            findings[key]["count"] += 1

    rounds = 0
    while time.monotonic() < end:
        rounds += 1
        one()
    work.stop()
    elapsed = clock.wall_s
    report(args, stats, stages, messages, findings, elapsed, rounds, slowest, seeds)


def report(args, stats, stages, messages, findings, elapsed, rounds, slowest, seeds) -> None:
    import hypothesis

    total = sum(stats.values())
    lines = [
        "# Fuzzing the LAS/LAZ reader",
        "",
        f"Command: `nice -n 10 python experiments/fuzz_reader.py --minutes {args.minutes:g}` "
        f"(hypothesis {hypothesis.__version__}, Python {sys.version.split()[0]}, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, shared 2-core CPU machine).",
        "",
        f"- {total:,} executions in {elapsed / 60:.1f} min ({total / max(elapsed, 1e-9):.0f}/s), "
        f"{rounds} hypothesis runs, {len(seeds)} seed files.",
        "- outcomes: " + ", ".join(f"{k} {v:,}" for k, v in sorted(stats.items())),
        "  (`input_error` = exit 2, `ok` = read, written and read back with every point, "
        "`ok_trusted` = refused, then read with --trust-data, written and read back).",
        "- stage reached (0 layout check failed, 1 laspy header failed, 2 read failed, 3 write/read-back "
        "failed, 4 all passed, 5 passed with --trust-data): " + ", ".join(f"{k}: {v:,}" for k, v in sorted(stages.items())),
        f"- slowest case: {slowest[0]:.2f} s ({slowest[1][:100]})",
        f"- unique findings (exit 1, hang > {HANG_S:.0f} s, crash): {len(findings)}",
        "",
    ]
    if findings:
        lines += ["| finding | count | example | reproducer |", "| --- | ---: | --- | --- |"]
        lines += [f"| {k} | {v['count']} | {v['example'][:120]} | `{v['file']}` |" for k, v in findings.items()]
        lines.append("")
    lines += ["Most frequent exit-2 messages:", ""]
    lines += [f"- {count:,} x `{message}`" for message, count in messages.most_common(15)]
    lines.append("")
    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
