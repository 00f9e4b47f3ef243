"""Reading recordings off the server's interpreter: every read that parses an MCAP file
for the API (the list's summaries of recordings not yet indexed, a review timeline,
the review's MP4) runs in a short-lived process of its own, one at a time, niced, with
a time limit and a memory limit, and its result is kept (``index``, ``.review/``).

Why a process and not a thread: decoding JSON holds the GIL, and a thread reading a
60 s recording's timeline held it for seconds against the event loop (the e-stop's,
the operator's commands: 2 033 of ~4 750 dropped as stale) and the force stream. In a
process the server's interpreter never waits for it; a read that runs too long is
killed; its memory is returned when it ends.

Who may make the server read: per remote address, a budget of reads
(``READS_PER_S``, an answer costing one more read per ``BYTES_PER_READ`` it sends) and
a smaller one of reads that start a job (``JOBS_PER_S``: what
is not kept yet), as ``/ws`` budgets connections (``backend/realtime/ratelimit.py``);
at most ``MAX_WAITING`` jobs wait behind the running one for clients without the
operator token (the operator's wait however long the line is). A job already running
or waiting for the same result is shared, not repeated. Waiting jobs run in the order
of their priority, then of their asking (``FIRST``: the review's video, what a review
page shows first; ``NEXT``: a timeline's first piece; ``LATER``: the rest).

``python -m telerobot.server.recording.readjobs`` is the job's process: one JSON request on
stdin, one JSON answer on stdout; it ends when its stdin closes (the server gone).
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import json
import logging
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from subprocess import PIPE
from typing import IO, Any

from telerobot.drivers.base import TelerobotError
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.recording.reader import UnreadableRecording
from telerobot.server.recording.salvage import NotARecording
from telerobot.tuning import started_yielding, yield_cpu

log = logging.getLogger(__name__)

JOB_TIMEOUT_S = 300.0  # a long recording's MP4 (the remux reads every frame)
JOB_MEMORY_BYTES = 2 * 1024**3  # address space of the job's process
JOB_NICE = 10  # it waits behind control, forces and live video
# A job reads one file in one thread: numpy's BLAS need not start a thread per core (at
# import, before the job could lower its priority: now it starts lowered anyway).
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
MAX_WAITING = 4  # jobs of tokenless clients waiting behind the running one
MAX_ANSWER_BYTES = 16 * 1024 * 1024  # a job's answer on stdout (summaries: ≤ 256 kB each)
STDERR_KEPT = 4096  # of a failed job's stderr: its last line goes to the log

READS_PER_S = 10.0  # recording reads a second from one address…
READ_BURST = 40  # …after a burst (the review page's first requests, a seek or two)
# A read's answer costs one more read per this many bytes: a loop of reads of a kept
# 2 MB timeline is ~5 MB/s from one address at most, not the 22 MB/s the server sent
# (and spent its event loop on) before (bench.abuse's timeline_reads).
BYTES_PER_READ = 512 * 1024
# …and from every tokenless client together, whatever the number of their addresses: six
# loopback addresses reading timelines at once took the operator's stale command drops
# from 59 to 517 in 25 s (a per-address budget alone grows with the addresses).
ALL_READS_PER_S = 15.0
ALL_READ_BURST = 60
ALL = "*"  # the shared budget's key
JOBS_PER_S = 0.5  # reads that start a job, from one address…
JOB_BURST = 8  # …after a burst (a review page: its list, MP4 and timeline's 3-6 pieces)
# The order jobs wait in (issue 55: a review page's first picture, then its first plots,
# were behind whatever was asked before them).
FIRST, NEXT, LATER = 0, 1, 2


class TooManyReads(TelerobotError):
    code = "too_many_reads"
    http_status = 429


class ReadsBusy(TelerobotError):
    code = "recording_reads_busy"
    http_status = 503


class ReadFailed(TelerobotError):
    code = "recording_read_failed"
    http_status = 503


class RecordingHasNoVideo(TelerobotError):
    code = "recording_no_video"
    http_status = 404


ERRORS: dict[str, type[TelerobotError]] = {
    c.code: c for c in (UnreadableRecording, NotARecording, RecordingHasNoVideo, ReadFailed)
}


@dataclass
class ReadBudgets:
    """Per remote address (``PeerLimits``, bounded like ``/ws``'s table), and one for
    all tokenless readers together (``everyone``)."""

    clock: Callable[[], float] = time.monotonic
    reads: PeerLimits = field(
        default_factory=lambda: PeerLimits(
            connections_per_s=READS_PER_S, connection_burst=READ_BURST
        )
    )
    jobs: PeerLimits = field(
        default_factory=lambda: PeerLimits(connections_per_s=JOBS_PER_S, connection_burst=JOB_BURST)
    )
    everyone: PeerLimits = field(
        default_factory=lambda: PeerLimits(
            connections_per_s=ALL_READS_PER_S, connection_burst=ALL_READ_BURST
        )
    )

    def read(self, peer: str) -> None:
        now = self.clock()
        if self.reads.connect(peer, now) is None:
            raise TooManyReads(
                f"too many recording reads from your address (at most {READS_PER_S:g} a"
                f" second, each {BYTES_PER_READ >> 10} KiB sent counting as one more): try"
                " again in a second, or with the operator token"
            )
        if self.everyone.connect(ALL, now) is None:
            raise TooManyReads(
                "too many recording reads from clients without the operator token right"
                f" now (at most {ALL_READS_PER_S:g} a second in all, whatever their"
                " addresses): try again in a second, or with the operator token"
            )

    def sent(self, peer: str, size: int) -> None:
        """The answer's size, charged to the address's reads and everyone's (the next
        reads wait)."""
        now = self.clock()
        self.reads.charge(peer, now, size / BYTES_PER_READ)
        self.everyone.charge(ALL, now, size / BYTES_PER_READ)

    def job(self, peer: str) -> None:
        if self.jobs.connect(peer, self.clock()) is None:
            raise TooManyReads(
                "too many reads of recordings not yet read (each is parsed once, then"
                f" kept) from your address (at most one every {1 / JOBS_PER_S:g} s): try"
                " again shortly, or with the operator token"
            )


class ReadJobs:
    """Runs jobs one at a time in their own processes (see the module)."""

    def __init__(self, *, timeout_s: float = JOB_TIMEOUT_S, max_waiting: int = MAX_WAITING) -> None:
        self.timeout_s = timeout_s
        self.max_waiting = max_waiting
        self._busy = False  # a job is running
        self._line: list[tuple[int, int, asyncio.Future[None]]] = []  # (priority, seq, go)
        self._seq = itertools.count()
        self._jobs: dict[str, asyncio.Task[dict[str, Any]]] = {}
        self._waiting = 0
        self.started = 0  # processes started (tests count them)

    async def run(
        self, key: str, request: dict[str, Any], *, privileged: bool, priority: int = LATER
    ) -> dict[str, Any]:
        """The job's answer: shared with a job of the same ``key`` under way."""
        task = self._jobs.get(key)
        if task is None:
            if not privileged and self._waiting >= self.max_waiting:
                raise ReadsBusy(
                    f"{self._waiting} reads of recordings are waiting: try again shortly"
                )
            task = asyncio.get_running_loop().create_task(self._queued(request, priority))
            self._jobs[key] = task
            task.add_done_callback(lambda t: self._done(key, t))
        return await asyncio.shield(task)  # a client that goes away leaves it to the others

    def _done(self, key: str, task: asyncio.Task[dict[str, Any]]) -> None:
        if self._jobs.get(key) is task:
            del self._jobs[key]
        if not task.cancelled():
            task.exception()  # retrieved: nobody may be left to await it

    async def _turn(self, priority: int) -> None:
        """Returns when it is this job's turn (the running one ended, and no job of a
        higher priority, or asked earlier at this one, is waiting)."""
        if not self._busy and not self._line:
            self._busy = True
            return
        go: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        entry = (priority, next(self._seq), go)
        heapq.heappush(self._line, entry)
        try:
            await go
        except asyncio.CancelledError:
            if go.done() and not go.cancelled():  # its turn had come: pass it on
                self._next()
            elif entry in self._line:
                self._line.remove(entry)
                heapq.heapify(self._line)
            raise

    def _next(self) -> None:
        """The running job ended: the next one's turn."""
        while self._line:
            _p, _s, go = heapq.heappop(self._line)
            if not go.done():
                go.set_result(None)
                return
        self._busy = False

    async def _queued(self, request: dict[str, Any], priority: int) -> dict[str, Any]:
        self._waiting += 1
        asked = time.monotonic()
        try:
            await self._turn(priority)
        finally:
            self._waiting -= 1
        started = time.monotonic()
        try:
            return await self._in_process(request)
        finally:
            self._next()
            log.info(
                "recording read job %s: %.2f s (after %.2f s waiting)",
                _what(request),
                time.monotonic() - started,
                started - asked,
            )

    async def _in_process(self, request: dict[str, Any]) -> dict[str, Any]:
        self.started += 1
        argv = started_yielding([sys.executable, "-m", __name__], JOB_NICE)
        line = json.dumps(request).encode() + b"\n"
        # Started by subprocess.Popen in a thread, not by the event loop's own
        # subprocess_exec: uvloop forks the whole server there (~300 MB of page tables,
        # then copy-on-write faults), 16 ms of a stalled loop per job, the e-stop's worst
        # case under tokenless timeline reads (bench.abuse); Popen vforks, ~0.3 ms, and
        # only in that thread.
        proc = await asyncio.to_thread(_start, argv, {**os.environ, **ONE_THREAD}, line)
        assert proc.stdin is not None and proc.stdout is not None and proc.stderr is not None
        transports: list[asyncio.BaseTransport] = []
        answered = False  # both pipes closed: the job is ending of itself
        try:
            stdout = await _stream(proc.stdout, transports)
            stderr = await _stream(proc.stderr, transports)
            out, err = await asyncio.wait_for(
                asyncio.gather(_bounded(stdout, MAX_ANSWER_BYTES), _tail(stderr)),
                self.timeout_s,
            )
            answered = True
        except TimeoutError:
            raise ReadFailed(
                f"reading the recording took longer than {self.timeout_s:g} s and was stopped"
            ) from None
        finally:
            if not answered:
                proc.kill()
            for transport in transports:
                transport.close()
            with contextlib.suppress(BrokenPipeError):
                proc.stdin.close()
            await asyncio.to_thread(proc.wait)
        try:
            answer = json.loads(out)
        except ValueError:
            last = err.decode(errors="replace").strip().splitlines()[-1:] or [""]
            log.warning(
                "a recording read ended without an answer (%s): %s", proc.returncode, last[0]
            )
            raise ReadFailed("reading the recording failed (the server's log says why)") from None
        error = answer.get("error")
        if error is not None:
            if error.get("logged"):
                log.warning("a recording read failed: %s", error["detail"])
            raise ERRORS.get(error.get("code"), ReadFailed)(str(error.get("detail")))
        result: dict[str, Any] = answer
        return result


def _what(request: dict[str, Any]) -> str:
    """A job in a few words, for the log: its kind, its file, a timeline's range."""
    name = Path(str(request.get("path") or "")).name or f"{len(request.get('paths', []))} files"
    kind, start, end = request.get("kind"), request.get("start_s"), request.get("end_s")
    if start is not None or end is not None:
        return f"{kind} {start or 0:g}-{'end' if end is None else f'{end:g}'} s of {name}"
    return f"{kind} of {name}"


def _start(argv: list[str], env: dict[str, str], line: bytes) -> subprocess.Popen[bytes]:
    """The job's process, its request written (a line: far below a pipe's buffer). Its
    stdin stays open until the job has answered: its end tells the job we have gone."""
    proc = subprocess.Popen(argv, stdin=PIPE, stdout=PIPE, stderr=PIPE, env=env)
    assert proc.stdin is not None
    with contextlib.suppress(BrokenPipeError):  # it ended at once: its stderr says why
        proc.stdin.write(line)
        proc.stdin.flush()
    return proc


async def _stream(pipe: IO[bytes], transports: list[asyncio.BaseTransport]) -> asyncio.StreamReader:
    """``pipe`` read by the event loop; its transport added to ``transports``."""
    reader = asyncio.StreamReader()
    transport, _ = await asyncio.get_running_loop().connect_read_pipe(
        lambda: asyncio.StreamReaderProtocol(reader), pipe
    )
    transports.append(transport)
    return reader


async def _bounded(stream: asyncio.StreamReader, limit: int) -> bytes:
    data = bytearray()
    while chunk := await stream.read(65536):
        data += chunk
        if len(data) > limit:
            raise ReadFailed(f"a recording read answered more than {limit} bytes")
    return bytes(data)


async def _tail(stream: asyncio.StreamReader) -> bytes:
    kept = b""
    while chunk := await stream.read(65536):
        kept = (kept + chunk)[-STDERR_KEPT:]
    return kept


# ---------------------------------------------------------------- the job's process
def _write_atomically(out: Path, data: bytes) -> None:
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, out)


def _finite(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value


def _json(value: Any) -> bytes:
    """Strict JSON (a browser refuses ``NaN``): a non-finite number becomes null."""
    try:
        return json.dumps(value, allow_nan=False).encode()
    except ValueError:
        return json.dumps(_finite(value), allow_nan=False).encode()


def do(request: dict[str, Any]) -> dict[str, Any]:
    """One job (in the job's process; tests call it directly)."""
    kind = request["kind"]
    if kind == "summaries":  # kept as they are made: a job cut short is not lost
        from telerobot.server.recording.index import RecordingIndex, summarise

        entries = []
        for p in map(Path, request["paths"]):
            entry = summarise(p)
            RecordingIndex(p.parent).put(entry)
            entries.append(entry)
        return {"entries": entries}
    if kind == "timeline":
        from telerobot.server.recording.timeline import timeline

        result = timeline(
            request["path"],
            request["topics"],
            request["max_points"],
            request.get("start_s"),
            request.get("end_s"),
            walk=request.get("walk"),
        )
        _write_atomically(Path(request["out"]), _json(result))
        return {"written": request["out"]}
    if kind == "mp4":
        from telerobot.server.recording.video import NoVideo, remux_mp4

        try:
            remux_mp4(request["path"], request["out"])
        except NoVideo as exc:
            raise RecordingHasNoVideo(str(exc)) from None
        return {"written": request["out"]}
    raise ValueError(f"unknown job {kind!r}")


def _exit_when_orphaned() -> None:
    """The server holds our stdin open while it waits for us: EOF means it has gone."""
    sys.stdin.buffer.read()
    os._exit(3)


def main() -> None:
    import resource
    import traceback

    yield_cpu(JOB_NICE)
    with contextlib.suppress(ValueError, OSError):
        resource.setrlimit(resource.RLIMIT_AS, (JOB_MEMORY_BYTES, JOB_MEMORY_BYTES))
    request = json.loads(sys.stdin.buffer.readline())
    threading.Thread(target=_exit_when_orphaned, daemon=True).start()
    try:
        answer = do(request)
    except TelerobotError as exc:
        answer = {"error": {"code": exc.code, "detail": str(exc)}}
    except MemoryError:
        answer = {
            "error": {
                "code": ReadFailed.code,
                "detail": f"reading the recording needed more than {JOB_MEMORY_BYTES >> 20} MiB",
            }
        }
    except Exception as exc:  # a file we did not foresee: refused, said once in the log
        traceback.print_exc()
        name = Path(str(request.get("path", ""))).name
        answer = {
            "error": {
                "code": UnreadableRecording.code,
                "detail": f"{name} could not be read ({type(exc).__name__}: {str(exc)[:200]})",
                "logged": True,
            }
        }
    sys.stdout.buffer.write(json.dumps(answer).encode())
    sys.stdout.buffer.flush()
    os._exit(0)  # not waiting for the orphan watcher's read


if __name__ == "__main__":
    main()
