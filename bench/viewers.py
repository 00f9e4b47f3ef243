"""Many viewers, directly and through the media server: what they cost the
robot's computer, what they cost the media server, and what the relay adds.

    python -m bench.viewers [--json] [--viewers 1,10,25,50] [--seconds 8] [--width 640]

One ``telerobot serve --media-server janus`` (simulation, stereo video at 2×640×360 and
30 fps by default, the arm moving between two poses as bench.video moves it; ``--still``
leaves it at rest) for the whole run. Its observers (no token) watch through Janus; the
operator (the token) gets the direct path, the robot's own aiortc peers. Every viewer
here takes the server's offer (``/webrtc/server-offer``, then ``/webrtc/answer``); the
direct ones ask for the full layer (``?layer=full``), which is what Janus is fed, so both
paths carry the same packets.

* **CPU** (cores) = (utime + stime) of a set of processes over a window ÷ the window,
  per process (psutil). ``robot_cpu``: the server's process and all its descendants except
  Janus (the media worker, ``telerobot-media``; the names are in ``robot_processes``).
  ``relay_cpu``: Janus's process (``media_server.pid`` of GET /api/v1/video), measured
  on both paths (idle on the direct one). Beside them, for judging the noise:
  ``receivers_cpu`` (the viewers' processes), ``bench_cpu`` (this script) and
  ``other_cpu``: every other process on the machine (such as a CI run; those that end
  within the window are missed). ``idle`` is the same with no viewer at all (the server
  then neither captures for nor encodes video).
* **Viewers**: aiortc peers in receiver processes of up to ``--per-process`` (13) peers
  each, so that one Python process is not the bottleneck. They do not decode: a hook on
  ``RTCRtpReceiver._handle_rtp_packet`` counts each RTP packet and feeds only aiortc's
  receiver statistics (so its RTCP receiver reports go out as a browser's do), never
  its jitter buffer or decoder, and they send no NACKs. Frames = packets with the
  marker bit. ``packets_lost`` = sequence numbers skipped, less those that came late.
  ``frames_lost`` (a lower bound) = frames with a packet missing, each counted once: a
  gap inside a frame (the packet before it had no marker bit) loses that frame; a gap
  right after a frame's marker loses the frame of the packet after it (its first
  packets, or whole frames in between, which count as one). Summed over the peers.
  ``fps_per_viewer_median``: frames per second of the median peer in the window. The
  relay's viewers open the media server's data channel, as an observer's page does
  (``--no-data-channel``: not), and count what comes on it (the observers' state and
  forces: ``data_messages_per_s_median``); the direct ones, operators, get theirs over
  the WebSocket, which is not run here.
* **Steps**: the idle baseline, the latency (below); then for each path and each
  ``--viewers`` count: connect them (a few at a time per process), wait until each has
  received a packet, settle 2 s, measure over ``--seconds``, close them all (DELETE
  /api/v1/webrtc/{peer_id} with X-Peer-Secret, then the peer connection) and wait until
  the server shows 0 viewers and 0 pending on both paths (``cleanup_s``; ``left_over``
  if it does not within 30 s).
  The direct path holds at most ``stats.max_viewers`` peers (16, pipeline.MAX_VIEWERS,
  no setting): counts above it are not measured there (``skipped``), that limit is.
* **Latency** (capture → the frame's last RTP packet): both paths at once, the same
  frames, one decoding peer each in its own process: the arrival of each frame's last
  packet (the latest of its RTP timestamp, noted by the hook), against the capture
  time drawn into the picture's timecode (drivers/camera/timecode; the camera's
  CLOCK_MONOTONIC, this machine's). ``relay_added_p50_ms`` / ``_p99_ms`` = the relay's
  percentile less the direct one's; ``relay_added_paired_*`` = percentiles of the
  per-frame difference (frames matched by their timecode, which counts 0.1 ms), over
  ``--latency-seconds``. The pipeline hands each frame to the media server's feed (one
  UDP send) before the direct peers' senders packetise and encrypt it in Python, so
  the relay can come out ahead: a negative figure.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import queue
import secrets
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import httpx

# No stubs installed for psutil (bench/ is outside the project's mypy files).
import psutil  # type: ignore[import-untyped]

from bench.common import machine, parser, percentiles_ms
from harness.aiortc_viewers import answer_server_offer
from harness.servers import serve_for_bench

REPO = Path(__file__).resolve().parents[1]
PATHS = ("direct", "relay")
TOKEN_ENV = "BENCH_VIEWERS_TOKEN"  # the operator token, for a direct receiver process
PER_PROCESS = 13  # peers per receiver process
CONNECT_AT_ONCE = 3  # per receiver process (the direct path takes 8 connecting at once)
CONNECT_ATTEMPTS = 3
FIRST_PACKET_S = 20.0  # a peer without a packet by then is not receiving
SETTLE_S = 2.0
CLEANUP_S = 30.0
MAX_LATENCY_S = 1.0  # a timecode read further from its frame's arrival is a misread


# ---------------------------------------------------------------- receiver processes
@dataclass
class PeerCount:
    """One peer's RTP as it arrives (frames_lost: see the module's docstring)."""

    decode: bool = False
    packets: int = 0
    frames: int = 0
    packets_lost: int = 0
    frames_lost: int = 0
    late: int = 0  # duplicates, or out of order
    other: int = 0  # not the video's payload type (retransmissions)
    data_messages: int = 0  # on the media server's data channel (observers' state, forces)
    first_at: float | None = None
    ext_seq: int | None = None  # the newest sequence number, extended past 16 bits
    ts: int | None = None  # the RTP timestamp of the frame in progress
    damaged: bool = False  # that frame is counted lost already
    after_marker: bool = True  # the newest packet ended its frame
    missing: set[int] = field(default_factory=set)
    receiving: asyncio.Event = field(default_factory=asyncio.Event)  # a first packet came
    last_packet_at: dict[int, float] = field(default_factory=dict)  # decode: ts → arrival

    def add(self, seq: int, ts: int, marker: bool, now: float) -> None:
        if self.decode:
            self.last_packet_at[ts] = now
            if len(self.last_packet_at) > 600:
                del self.last_packet_at[next(iter(self.last_packet_at))]
        if self.first_at is None:
            self.first_at = now
            self.receiving.set()
        if self.ext_seq is None:
            self.ext_seq, self.ts, self.after_marker = seq, ts, marker
            self.packets += 1
            self.frames += marker
            return
        ahead = (seq - self.ext_seq) & 0xFFFF
        if ahead == 0 or ahead >= 0x8000:
            back = self.ext_seq - ((self.ext_seq - seq) & 0xFFFF)
            if back in self.missing:
                self.missing.discard(back)
                self.packets_lost -= 1
            self.late += 1
            return
        self.packets += 1
        gap = ahead - 1
        if gap:
            self.packets_lost += gap
            if gap <= 512:
                self.missing.update(range(self.ext_seq + 1, self.ext_seq + ahead))
            if len(self.missing) > 4096:
                self.missing = {s for s in self.missing if s > self.ext_seq - 2048}
        self.ext_seq += ahead
        if gap and not self.after_marker:  # the frame in progress lost its middle or tail
            self.frames_lost += not self.damaged
            self.damaged = True
        if ts != self.ts:
            self.ts, self.damaged = ts, False
        if gap and self.after_marker:  # this packet's frame lost its head (or more)
            self.frames_lost += not self.damaged
            self.damaged = True
        self.after_marker = marker
        self.frames += marker

    def snapshot(self) -> dict[str, int]:
        return {
            "packets": self.packets,
            "frames": self.frames,
            "packets_lost": self.packets_lost,
            "frames_lost": self.frames_lost,
            "late": self.late,
            "other": self.other,
            "data_messages": self.data_messages,
        }


def _install_counting_hook() -> None:
    """Every receiver with a ``bench_count`` counts its RTP there; only the decoding
    ones pass it on to aiortc (jitter buffer, NACKs, decoder)."""
    import aiortc.rtcrtpreceiver as receiver
    from aiortc.codecs import is_rtx

    original = receiver.RTCRtpReceiver._handle_rtp_packet

    async def handle(self: Any, packet: Any, arrival_time_ms: int) -> None:
        count: PeerCount | None = getattr(self, "bench_count", None)
        if count is None:
            await original(self, packet, arrival_time_ms)
            return
        codec = self._RTCRtpReceiver__codecs.get(packet.payload_type)
        video = codec is not None and not is_rtx(codec)
        if video:
            count.add(packet.sequence_number, packet.timestamp, packet.marker, time.monotonic())
        else:
            count.other += 1
        if count.decode:
            await original(self, packet, arrival_time_ms)
        elif video:  # what its RTCP receiver reports are made of
            streams = self._RTCRtpReceiver__remote_streams
            stats = streams.get(packet.ssrc)
            if stats is None:
                stats = streams[packet.ssrc] = receiver.StreamStatistics(codec.clockRate)
            stats.add(packet)

    receiver.RTCRtpReceiver._handle_rtp_packet = handle  # type: ignore[method-assign]


@dataclass
class Viewer:
    count: PeerCount
    pc: Any = None
    track: Any = None
    peer: dict[str, str] | None = None
    errors: list[str] = field(default_factory=list)
    # Decoding peers: (capture timecode, capture → last packet in s, decoded at)
    latencies: list[tuple[int, float, float]] = field(default_factory=list)
    unreadable: int = 0
    timed: asyncio.Event = field(default_factory=asyncio.Event)  # a first frame timed
    reader: asyncio.Task[None] | None = None


def _say(event: str, **figures: Any) -> None:
    print(json.dumps({"event": event, **figures}), flush=True)


async def _connect(http: httpx.AsyncClient, v: Viewer, layer: str, data: bool) -> None:
    from aiortc import RTCPeerConnection

    v.pc = pc = RTCPeerConnection()
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)

    def before_answer(offer: dict[str, Any]) -> None:
        v.peer = {"peer_id": offer["peer_id"], "peer_secret": offer["peer_secret"]}
        if data and "m=application" in offer["sdp"]:
            # As an observer's page does: the media server opens none itself, and sends
            # its state and forces on this one.
            channel = pc.createDataChannel("JanusDataChannel")

            @channel.on("message")
            def on_message(message: bytes | str) -> None:
                v.count.data_messages += 1

        for transceiver in pc.getTransceivers():
            transceiver.receiver.bench_count = v.count  # type: ignore[attr-defined]

    await answer_server_offer(http, pc, layer, before_answer)
    v.track = await asyncio.wait_for(tracks.get(), 10)


async def _read_frames(v: Viewer, full_width: int) -> None:
    """A decoding peer: each frame's capture time (timecode) against the arrival of its
    last RTP packet (its RTP timestamp = the receiver's pts + the mapper's origin)."""
    from telerobot.drivers.camera import timecode

    mapper = v.pc.getTransceivers()[0].receiver._RTCRtpReceiver__timestamp_mapper
    while True:
        frame = await v.track.recv()
        now = time.monotonic()
        origin = mapper._origin
        arrival = None
        if origin is not None and frame.pts is not None:
            arrival = v.count.last_packet_at.get((frame.pts + origin) % (1 << 32))
        luma = frame.to_ndarray()  # yuv420p: the first `height` rows are Y
        eye = luma[: frame.height, : frame.width // 2]
        code = timecode.read(eye, scale=eye.shape[1] / full_width)
        if code is None or arrival is None:
            v.unreadable += 1
            continue
        age = timecode.elapsed(code, arrival)
        if age > MAX_LATENCY_S:
            v.unreadable += 1
            continue
        v.latencies.append((code, age, now))
        v.timed.set()


async def _open(
    http: httpx.AsyncClient,
    v: Viewer,
    gate: asyncio.Semaphore,
    layer: str,
    data: bool,
    full_width: int,
) -> None:
    async with gate:  # held until it receives: a connecting peer is "pending" on the server
        for attempt in range(CONNECT_ATTEMPTS):
            try:
                await _connect(http, v, layer, data)
                deadline = time.monotonic() + FIRST_PACKET_S
                try:
                    await asyncio.wait_for(v.count.receiving.wait(), FIRST_PACKET_S)
                except TimeoutError:
                    raise RuntimeError(f"no RTP packet within {FIRST_PACKET_S:g} s") from None
                if v.count.decode:
                    v.reader = asyncio.create_task(_read_frames(v, full_width))
                    with contextlib.suppress(TimeoutError):  # its figures say if none came
                        await asyncio.wait_for(v.timed.wait(), deadline - time.monotonic())
                return
            except Exception as exc:
                v.errors.append(f"attempt {attempt + 1}: {type(exc).__name__}: {exc}"[:400])
                await _close(http, v)
                await asyncio.sleep(1.0)


async def _close(http: httpx.AsyncClient, v: Viewer) -> None:
    if v.reader is not None:
        v.reader.cancel()
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await v.reader
        v.reader = None
    if v.peer is not None:
        with contextlib.suppress(httpx.HTTPError):
            r = await http.delete(
                f"api/v1/webrtc/{v.peer['peer_id']}",
                headers={"X-Peer-Secret": v.peer["peer_secret"]},
            )
            if r.status_code != 200:
                v.errors.append(f"DELETE: HTTP {r.status_code} {r.text[:200]}")
        v.peer = None
    if v.pc is not None:
        with contextlib.suppress(Exception):
            await v.pc.close()
        v.pc = None


def _stdin_lines(loop: asyncio.AbstractEventLoop) -> asyncio.Queue[str]:
    lines: asyncio.Queue[str] = asyncio.Queue()

    def read() -> None:
        for line in sys.stdin:
            loop.call_soon_threadsafe(lines.put_nowait, line.strip())
        loop.call_soon_threadsafe(lines.put_nowait, "eof")

    threading.Thread(target=read, daemon=True).start()
    return lines


def role_receivers(
    base: str, count: int, measure: int, path: str, data: bool, full_width: int
) -> None:
    """``measure`` decoding peers and ``count`` counting ones on one path. Says
    ``ready``, then waits for ``start`` and ``stop`` on stdin, says ``result`` (the
    window's counts), closes its peers and says ``closed``."""
    _install_counting_hook()
    token = os.environ.get(TOKEN_ENV, "") if path == "direct" else ""
    headers = {"X-Telerobot-Client": "bench.viewers"}  # a DELETE has no JSON body
    if token:
        headers["Authorization"] = f"Bearer {token}"
    layer = "full"  # direct: what Janus gets; the media server's offer ignores it

    async def run() -> None:
        lines = _stdin_lines(asyncio.get_running_loop())
        viewers = [Viewer(PeerCount(decode=i < measure)) for i in range(measure + count)]
        async with httpx.AsyncClient(base_url=base, timeout=30, headers=headers) as http:
            gate = asyncio.Semaphore(CONNECT_AT_ONCE)
            await asyncio.gather(*(_open(http, v, gate, layer, data, full_width) for v in viewers))
            _say(
                "ready",
                receiving=sum(1 for v in viewers if v.peer is not None),
                errors=[e for v in viewers for e in v.errors],
            )
            while (line := await lines.get()) not in ("start", "stop", "eof"):
                pass
            t0 = time.monotonic()
            before = [v.count.snapshot() for v in viewers]
            _say("started", at=t0)
            while line not in ("stop", "eof"):
                line = await lines.get()
            t1 = time.monotonic()
            after = [v.count.snapshot() for v in viewers]
            peers = [
                {
                    **{k: a[k] - b[k] for k in a},
                    "connected": v.peer is not None,
                    "decode": v.count.decode,
                }
                for v, b, a in zip(viewers, before, after, strict=True)
            ]
            latencies = [
                (code, age) for v in viewers for code, age, at in v.latencies if t0 <= at <= t1
            ]
            _say(
                "result",
                window_s=t1 - t0,
                peers=peers,
                latencies=latencies,
                unreadable=sum(v.unreadable for v in viewers),
            )
            opened = [len(v.errors) for v in viewers]
            await asyncio.gather(*(_close(http, v) for v in viewers))
            _say(
                "closed",
                errors=[e for v, n in zip(viewers, opened, strict=True) for e in v.errors[n:]],
            )

    asyncio.run(run())


# ---------------------------------------------------------------- CPU per process
@dataclass(frozen=True)
class ProcStat:
    name: str
    started: float  # its creation time: with the pid, names one process
    cpu_s: float  # user + system, all its threads


def every_process() -> dict[int, ProcStat]:
    found = {}
    for p in psutil.process_iter(["name", "create_time", "cpu_times"]):
        times = p.info["cpu_times"]
        if times is not None:  # None: gone, or not ours to read
            found[p.pid] = ProcStat(
                p.info["name"] or "?", p.info["create_time"], times.user + times.system
            )
    return found


def descendants(root: int) -> list[int]:
    with contextlib.suppress(psutil.NoSuchProcess):
        return [c.pid for c in psutil.Process(root).children(recursive=True)]
    return []


def _describe(pid: int) -> str:
    """Its pid, name and command line (cut), for the record."""
    try:
        p = psutil.Process(pid)
        return f"{pid} {p.name()}: {' '.join(p.cmdline())[:120]}"
    except psutil.Error:
        return f"{pid} ?"


@dataclass
class CpuWindow:
    """CPU seconds of every process at the start of a window; ``end`` gives the robot's,
    Janus's, the receivers' and everyone else's in cores. (Not /proc/stat's busy time:
    on this virtual machine its tick sampling misses most of the short bursts an event
    loop runs in, reading 0.01 cores while the idle server alone takes 0.1.)"""

    robot: list[int]
    janus: int | None
    receivers: list[int]
    at: float = 0.0
    start: dict[int, ProcStat] = field(default_factory=dict)

    def begin(self) -> CpuWindow:
        self.start, self.at = every_process(), time.monotonic()
        return self

    def end(self) -> dict[str, float]:
        now, wall = every_process(), time.monotonic() - self.at

        def used(pid: int) -> float:
            s, was = now.get(pid), self.start.get(pid)
            if s is None:
                return 0.0  # ended within the window: its time is lost with it
            return s.cpu_s - (was.cpu_s if was is not None and was.started == s.started else 0)

        def cores(pids: list[int]) -> float:
            return sum(used(pid) for pid in pids) / wall

        ours = {*self.robot, *self.receivers, os.getpid(), *([self.janus] if self.janus else [])}
        return {
            "robot_cpu": cores(self.robot),
            "relay_cpu": cores([self.janus] if self.janus else []),
            "receivers_cpu": cores(self.receivers),
            "other_cpu": cores([pid for pid in now if pid not in ours]),
            "bench_cpu": cores([os.getpid()]),
            "cpu_window_s": wall,
        }


# ---------------------------------------------------------------- the run
class Receivers:
    """One receiver process (``--role receivers``) and its JSON lines."""

    def __init__(
        self,
        base: str,
        path: str,
        count: int,
        measure: int,
        token: str,
        full_width: int,
        data: bool,
    ) -> None:
        self.err: IO[str] = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (closed in finish)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bench.viewers", "--role", "receivers", "--base", base,
             "--path", path, "--count", str(count), "--measure", str(measure),
             "--full-width", str(full_width), *([] if data else ["--no-data-channel"])],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.err, text=True,
            env={**os.environ, TOKEN_ENV: token}, cwd=REPO,
        )  # fmt: skip
        self.lines: queue.Queue[dict[str, Any] | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            if line.startswith("{"):
                with contextlib.suppress(ValueError):
                    self.lines.put(json.loads(line))
        self.lines.put(None)

    def stderr_tail(self) -> str:
        self.err.seek(0)
        return self.err.read()[-3000:]

    def expect(self, event: str, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            try:
                item = self.lines.get(timeout=max(0.01, deadline - time.monotonic()))
            except queue.Empty:
                raise RuntimeError(
                    f"receivers: no {event!r} within {timeout:g} s\n{self.stderr_tail()}"
                ) from None
            if item is None:
                raise RuntimeError(f"receivers exited before {event!r}:\n{self.stderr_tail()}")
            if item.get("event") == event:
                return item

    def send(self, word: str) -> None:
        assert self.proc.stdin is not None
        with contextlib.suppress(OSError):
            self.proc.stdin.write(word + "\n")
            self.proc.stdin.flush()

    def finish(self, timeout: float = 60.0) -> list[str]:
        """Its peers closed and the process ended; the errors it reported closing them."""
        errors: list[str] = []
        try:
            errors = self.expect("closed", timeout).get("errors", [])
            self.proc.wait(timeout=10)
        except (RuntimeError, subprocess.TimeoutExpired) as exc:
            errors.append(f"receivers did not close cleanly: {exc}"[:400])
            self.proc.kill()
            self.proc.wait()
        self.err.close()
        return errors


def _split(n: int, per: int) -> list[int]:
    k = max(1, -(-n // per))
    return [n // k + (1 if i < n % k else 0) for i in range(k)]


@dataclass
class Bench:
    base: str
    token: str
    server_pid: int
    full_width: int
    seconds: float
    per_process: int
    data: bool
    janus_pid: int | None = None
    robot: list[int] = field(default_factory=list)

    def video(self) -> dict[str, Any]:
        r = httpx.get(
            self.base + "api/v1/video",
            headers={"Authorization": f"Bearer {self.token}"},
            timeout=15,
        )
        status: dict[str, Any] = r.json()
        return status

    def find_processes(self) -> dict[str, Any]:
        status = self.video()
        self.janus_pid = (status.get("media_server") or {}).get("pid")
        below = descendants(self.server_pid)
        janus_family = set()
        if self.janus_pid is not None:
            janus_family = {self.janus_pid, *descendants(self.janus_pid)}
        self.robot = [self.server_pid, *(p for p in below if p not in janus_family)]
        return {
            "robot_processes": [_describe(pid) for pid in self.robot],
            "janus_process": None if self.janus_pid is None else _describe(self.janus_pid),
            "janus_is_server_child": self.janus_pid in below,
        }

    def window(self, receivers: list[Receivers]) -> CpuWindow:
        pids = [r.proc.pid for r in receivers]
        return CpuWindow(self.robot, self.janus_pid, pids).begin()

    def wait_empty(self) -> tuple[float | None, dict[str, Any] | None]:
        """Until both paths show 0 viewers and 0 pending: seconds taken, or None and
        what was left."""
        t0 = time.monotonic()
        left: dict[str, Any] = {}
        while time.monotonic() - t0 < CLEANUP_S:
            stats = self.video().get("stats") or {}
            relay = stats.get("relay") or {}
            left = {
                "direct_viewers": stats.get("viewer_count"),
                "direct_pending": stats.get("pending"),
                "relay_viewers": relay.get("viewers"),
                "relay_pending": relay.get("pending"),
            }
            if all(v == 0 for v in left.values()):
                return time.monotonic() - t0, None
            time.sleep(0.25)
        return None, left

    def spawn(self, path: str, count: int, measure: int = 0) -> list[Receivers]:
        sizes = _split(count, self.per_process) if count else [0]
        return [
            Receivers(
                self.base, path, n, measure if i == 0 else 0, self.token, self.full_width, self.data
            )
            for i, n in enumerate(sizes)
        ]

    def run(self, groups: list[Receivers], seconds: float) -> dict[str, Any]:
        """Connect, settle, measure, close; the figures of the window."""
        readies, results, close_errors = [], [], []
        try:
            t_connect = time.monotonic()
            readies = [r.expect("ready", timeout=180) for r in groups]
            connect_s = time.monotonic() - t_connect
            time.sleep(SETTLE_S)
            v0, t_v0 = self.video(), time.monotonic()
            cpu = self.window(groups)
            for r in groups:
                r.send("start")
            for r in groups:
                r.expect("started", timeout=30)
            time.sleep(seconds)
            for r in groups:
                r.send("stop")
            figures = cpu.end()
            v1, t_v1 = self.video(), time.monotonic()
            results = [r.expect("result", timeout=60) for r in groups]
        finally:
            for r in groups:
                r.send("stop")
            for r in groups:
                close_errors.extend(r.finish())
        cleanup_s, left = self.wait_empty()
        peers = [p for res in results for p in res["peers"]]
        counting = [p for p in peers if not p["decode"]]
        fps = sorted(
            p["frames"] / res["window_s"]
            for res in results
            for p in res["peers"]
            if not p["decode"]
        )
        data_rates = [
            p["data_messages"] / res["window_s"]
            for res in results
            for p in res["peers"]
            if not p["decode"]
        ]
        s0, s1 = v0.get("stats") or {}, v1.get("stats") or {}
        r0, r1 = s0.get("relay") or {}, s1.get("relay") or {}

        def delta(a: dict[str, Any], b: dict[str, Any], key: str) -> Any:
            return None if a.get(key) is None or b.get(key) is None else b[key] - a[key]

        encoded = delta(s0, s1, "frames_encoded")
        connect_errors = [e for ready in readies for e in ready.get("errors", [])]
        return {
            **figures,
            "viewers_requested": sum(1 for p in peers if not p["decode"]),
            "viewers_receiving": sum(1 for p in counting if p["packets"] > 0),
            "frames_lost": sum(p["frames_lost"] for p in peers),
            "packets_lost": sum(p["packets_lost"] for p in peers),
            "packets_late": sum(p["late"] for p in peers),
            "packets": sum(p["packets"] for p in peers),
            "fps_per_viewer_median": statistics.median(fps) if fps else None,
            "fps_per_viewer_min": fps[0] if fps else None,
            "data_messages_per_s_median": statistics.median(data_rates) if data_rates else None,
            "encoder_fps": None if encoded is None else encoded / (t_v1 - t_v0),
            "full_layer_kbps": ((s1.get("layers") or {}).get("full") or {}).get("kbps"),
            "key_frames_forced": delta(s0, s1, "keyframes_forced"),
            "relay_rtp_packets": delta(r0, r1, "rtp_packets"),
            "relay_key_frame_requests": delta(r0, r1, "key_frame_requests"),
            "connect_s": connect_s,
            "connect_errors": len(connect_errors),
            "connect_error_examples": connect_errors[:3],
            "close_errors": close_errors[:3],
            "cleanup_s": cleanup_s,
            "left_over": left,
        }

    def latency(self, seconds: float) -> dict[str, Any]:
        """One decoding peer per path, at the same time, on the same frames."""
        groups = {path: self.spawn(path, 0, measure=1) for path in PATHS}
        readies = {p: g[0].expect("ready", timeout=120) for p, g in groups.items()}
        try:
            time.sleep(SETTLE_S)
            for g in groups.values():
                g[0].send("start")
            for g in groups.values():
                g[0].expect("started", timeout=30)
            time.sleep(seconds)
            for g in groups.values():
                g[0].send("stop")
            results = {p: g[0].expect("result", timeout=60) for p, g in groups.items()}
        finally:
            for g in groups.values():
                g[0].send("stop")
            close_errors = [e for g in groups.values() for e in g[0].finish()]
        cleanup_s, left = self.wait_empty()
        out: dict[str, Any] = {}
        ages = {p: {code: age for code, age in res["latencies"]} for p, res in results.items()}
        for path, res in results.items():
            values = list(ages[path].values())
            peer = res["peers"][0] if res["peers"] else {}
            out[path] = {
                **(percentiles_ms(values) if values else {}),
                "frames_timed": len(values),
                "unreadable": res["unreadable"],
                "frames_lost": peer.get("frames_lost"),
                "packets_lost": peer.get("packets_lost"),
                "connect_errors": readies[path].get("errors", [])[:3],
            }
        paired = [
            ages["relay"][c] - ages["direct"][c] for c in ages["relay"] if c in ages["direct"]
        ]
        out["paired"] = {
            **(percentiles_ms(paired) if paired else {}),
            "frames": len(paired),
        }
        out["close_errors"] = close_errors[:3]
        out["cleanup_s"], out["left_over"] = cleanup_s, left
        return out


POSES = ([0.4, 0.6, -2.8, 0.3, 0.6, 0.5], [-0.3, 0.9, -3.0, -0.3, 0.9, -0.5])  # bench.video's


def drive_arm(base: str, token: str, stop: threading.Event, done: dict[str, Any]) -> None:
    """Keep the simulated arm moving between two poses (as bench.video does), so the
    frames change as they would in use; ``done`` counts the moves and keeps the errors."""
    h = {"Authorization": f"Bearer {token}"}
    try:
        with httpx.Client(base_url=base, timeout=60) as http:
            r = http.post("api/v1/lease", json={"name": "bench.viewers"}, headers=h)
            r.raise_for_status()
            h["X-Client-Id"] = r.json()["client_id"]
            while not stop.is_set():
                body = {"space": "joint", "mode": "absolute", "joints": POSES[done["moves"] % 2]}
                r = http.post("api/v1/robot/move", json=body, headers=h)
                if r.status_code != 200:
                    done["errors"].append(f"HTTP {r.status_code} {r.text[:200]}")
                    stop.wait(1.0)
                done["moves"] += 1
    except Exception as exc:  # the figures stand without it; say so
        done["errors"].append(f"{type(exc).__name__}: {exc}"[:300])


def _row(name: str, n: int | str, fig: dict[str, Any]) -> str:
    def f(key: str, fmt: str = ".3f") -> str:
        v = fig.get(key)
        return "-" if v is None else format(v, fmt)

    return (
        f"{name:<7}{n!s:>5}{f('viewers_receiving', 'd'):>6}{f('robot_cpu'):>8}{f('relay_cpu'):>8}"
        f"{f('receivers_cpu'):>8}{f('other_cpu'):>8}{f('fps_per_viewer_median', '.1f'):>7}"
        f"{f('encoder_fps', '.1f'):>7}{f('frames_lost', 'd'):>7}{f('packets_lost', 'd'):>7}"
        f"{f('cleanup_s', '.1f'):>8}"
    )


HEADER = (
    f"{'path':<7}{'n':>5}{'recv':>6}{'robot':>8}{'relay':>8}{'rcvrs':>8}{'other':>8}"
    f"{'fps':>7}{'enc':>7}{'f_lost':>7}{'p_lost':>7}{'clean_s':>8}"
)
POINT_KEYS = (
    "robot_cpu", "relay_cpu", "frames_lost", "packets_lost", "viewers_requested",
    "viewers_receiving", "fps_per_viewer_median", "fps_per_viewer_min",
    "data_messages_per_s_median", "encoder_fps",
    "full_layer_kbps", "receivers_cpu", "other_cpu", "bench_cpu", "cpu_window_s",
    "packets", "packets_late", "key_frames_forced", "relay_rtp_packets",
    "relay_key_frame_requests", "connect_s", "connect_errors", "connect_error_examples",
    "close_errors", "cleanup_s", "left_over",
)  # fmt: skip


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--viewers", default="1,10,25,50", help="comma-separated viewer counts")
    p.add_argument("--seconds", type=float, default=8.0, help="CPU window per point")
    p.add_argument("--latency-seconds", type=float, default=10.0)
    p.add_argument("--width", type=int, default=640, help="of one eye")
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--per-process", type=int, default=PER_PROCESS, help="peers per receiver")
    p.add_argument("--still", action="store_true", help="leave the arm at rest")
    p.add_argument(
        "--no-data-channel",
        action="store_true",
        help="relay viewers open no data channel (an observer's page opens one: state, forces)",
    )
    p.add_argument("--role", choices=("receivers",), help=argparse.SUPPRESS)
    p.add_argument("--base", help=argparse.SUPPRESS)
    p.add_argument("--path", choices=PATHS, help=argparse.SUPPRESS)
    p.add_argument("--count", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--measure", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--full-width", type=int, default=640, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role:
        role_receivers(
            args.base,
            args.count,
            args.measure,
            args.path,
            not args.no_data_channel,
            args.full_width,
        )
        return
    counts = sorted({int(x) for x in args.viewers.split(",") if x.strip()})
    if not counts or counts[0] < 1:
        p.error("--viewers: counts of at least 1")
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_VIDEO": "true",
        # Direct at 25 and 50 too (the server's default holds 16 peers)
        "TELEROBOT_VIDEO_MAX_VIEWERS": str(max(1 + max(counts, default=1), 16)),
        "TELEROBOT_VIDEO_WIDTH": str(args.width),
        "TELEROBOT_VIDEO_HEIGHT": str(args.height),
        "TELEROBOT_VIDEO_FPS": str(args.fps),
        "TELEROBOT_OPERATOR_TOKEN": token,
    }
    started = time.monotonic()
    figures: dict[str, Any] = {"direct": {}, "relay": {}}
    with serve_for_bench("--media-server", "janus", env=env) as (proc, base):
        bench = Bench(
            base, token, proc.pid, args.width, args.seconds, args.per_process,
            not args.no_data_channel,
        )  # fmt: skip
        deadline = time.monotonic() + 60
        while True:
            status = bench.video()
            if (
                status.get("worker_alive")
                and status.get("stats")
                and (status.get("media_server") or {}).get("state") == "running"
            ):
                break
            if time.monotonic() > deadline:
                raise RuntimeError(f"the server's video is not up: {status}")
            time.sleep(0.5)
        time.sleep(max(0.0, started + 5.0 - time.monotonic()))  # the arm initialises
        processes = bench.find_processes()
        direct_max = int((status.get("stats") or {}).get("max_viewers") or 16)
        stop_arm = threading.Event()
        arm: dict[str, Any] = {"moves": 0, "errors": []}
        if not args.still:
            threading.Thread(
                target=drive_arm, args=(base, token, stop_arm, arm), daemon=True
            ).start()
            time.sleep(2.0)
        print(HEADER, flush=True)
        cpu = bench.window([])
        time.sleep(args.seconds)
        idle = {**cpu.end(), "viewers_receiving": 0}
        print(_row("idle", 0, idle), flush=True)

        latency = bench.latency(args.latency_seconds)
        for path in PATHS:
            lat = latency[path]
            print(
                f"latency {path}: capture → last packet p50 {lat.get('p50_ms', float('nan')):.2f}"
                f" p99 {lat.get('p99_ms', float('nan')):.2f} ms ({lat['frames_timed']} frames)",
                flush=True,
            )

        for path in PATHS:
            points = counts
            if path == "direct" and counts[-1] > direct_max:
                points = sorted({*counts, direct_max})  # the most it holds, measured
            for n in points:
                if path == "direct" and n > direct_max:
                    figures[path][str(n)] = {
                        "robot_cpu": None,
                        "relay_cpu": None,
                        "frames_lost": None,
                        "viewers_receiving": 0,
                        "skipped": f"the direct path holds at most {direct_max} peers"
                        " (stats.max_viewers: backend/media/pipeline.py MAX_VIEWERS)",
                    }
                    print(f"{path:<7}{n:>5}  skipped: over the direct limit of {direct_max}")
                    continue
                point = bench.run(bench.spawn(path, n), args.seconds)
                figures[path][str(n)] = {k: point[k] for k in POINT_KEYS}
                print(_row(path, n, point), flush=True)
                if point["connect_errors"] or point["left_over"] or point["close_errors"]:
                    print(
                        f"    connect errors {point['connect_errors']}"
                        f" {point['connect_error_examples']}; close {point['close_errors']};"
                        f" left over {point['left_over']}",
                        flush=True,
                    )
        stop_arm.set()
        final = bench.video()
    lo, hi = str(counts[0]), str(counts[-1])

    def ratio(path: str, a: str, b: str) -> float | None:
        x, y = figures[path].get(b, {}).get("robot_cpu"), figures[path].get(a, {}).get("robot_cpu")
        return None if x is None or not y else x / y

    measured_direct = [n for n in figures["direct"] if figures["direct"][n].get("robot_cpu")]
    direct_top = max(measured_direct, key=int, default=lo)
    d, r = latency["direct"], latency["relay"]
    added_p50 = r["p50_ms"] - d["p50_ms"] if "p50_ms" in r and "p50_ms" in d else None
    added_p99 = r["p99_ms"] - d["p99_ms"] if "p99_ms" in r and "p99_ms" in d else None
    relay_ratio = ratio("relay", lo, hi)
    lost = {path: sum(v.get("frames_lost") or 0 for v in figures[path].values()) for path in PATHS}
    summary: dict[str, Any] = {
        f"robot_cpu_ratio_{hi}_vs_{lo}": relay_ratio,
        f"direct_robot_cpu_ratio_{hi}_vs_{lo}": ratio("direct", lo, hi),
        f"direct_robot_cpu_ratio_{direct_top}_vs_{lo}": ratio("direct", lo, direct_top),
        "relay_added_p50_ms": added_p50,
        "relay_added_p99_ms": added_p99,
        "relay_added_paired_p50_ms": latency["paired"].get("p50_ms"),
        "relay_added_paired_p99_ms": latency["paired"].get("p99_ms"),
        "latency": latency,
        "idle": idle,
        "frames_lost_total": lost,
        "goals": {
            f"robot_cpu_ratio_{hi}_vs_{lo}_le_1_1": relay_ratio is not None and relay_ratio <= 1.1,
            "relay_added_p50_le_3ms": added_p50 is not None and added_p50 <= 3.0,
            "no_frames_lost": lost["direct"] == 0
            and lost["relay"] == 0
            and not d.get("frames_lost")
            and not r.get("frames_lost"),
        },
        "direct_max_viewers": direct_max,
        "processes": processes,
        "media_server_at_end": final.get("media_server"),
        "media_worker_restarts": final.get("worker_restarts"),
        "relay_at_end": (final.get("stats") or {}).get("relay"),
        "relay_viewers_data_channel": not args.no_data_channel,
        "arm": "still" if args.still else {"moves": arm["moves"], "errors": arm["errors"][:3]},
        "video": {"width_per_eye": args.width, "height": args.height, "fps": args.fps},
        "seconds": args.seconds,
        "latency_seconds": args.latency_seconds,
        "wall_s": time.monotonic() - started,
        "machine": machine(),
        "load_average": list(os.getloadavg()),
    }
    print(
        f"relay added (p50 diff / p99 diff): {added_p50} / {added_p99} ms;"
        f" paired p50 {summary['relay_added_paired_p50_ms']}"
        f" p99 {summary['relay_added_paired_p99_ms']} ms"
    )
    print(f"robot CPU {hi} vs {lo} viewers through the relay: {relay_ratio}")
    print(f"goals {summary['goals']}")
    print(f"wall time {summary['wall_s']:.0f} s")
    if args.json:
        print(json.dumps({**figures, **summary}))


if __name__ == "__main__":
    main()
