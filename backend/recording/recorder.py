"""The Recorder service: one MCAP file per recording, written off the
realtime paths.

``log(topic, payload, t=None)`` is non-blocking and thread-safe (the event loop, the
force sensor's thread and the video encoder call it): it puts the message on the
recording's bounded queue, or, if the queue is full, drops it and counts the drop
per topic. A forwarding thread hands what has queued, every ``BATCH_S``, to the
recording's own writer process (``writer.serve_file``), which encodes and writes: the
JSON, base64 and zstd work never holds this process's GIL against the force stream
and the event loop (in a thread here it put +0.3–0.5 ms on the force p99). A failing
write (a full disk, the writer killed, any error) ends the recording with the reason
on ``events``; it never raises into a caller and the robot is not touched. The file
written so far keeps every complete chunk: ``reader.recover`` gives it a summary.

``RecordingTaps`` subscribes the recorder to the robot's streams (force samples,
state at the state rate, every command, safety changes) without touching their
paths beyond one ``log`` call.

A recording stops by itself, with the reason kept in the list, when its file reaches
``max_bytes`` (the setting ``recording_max_bytes``) or the disk's free space falls
below ``min_free_bytes`` (``recording_min_free_bytes``), and does not start below it:
the file is closed whole rather than cut by ENOSPC. What the list shows of a recording
is kept in its index (``telerobot.server.recording.index``) when it closes, reasons included.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import datetime as dt
import json
import logging
import multiprocessing
import multiprocessing.process
import queue
import re
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from telerobot.drivers.base import ForceSample, ForceSensor, InvalidCommand, TelerobotError
from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import CommandReport, DecisionServer, SafetyState
from telerobot.server.recording import schemas as ch
from telerobot.server.recording.arms import recorded_arms
from telerobot.server.recording.library import RecordingLibrary
from telerobot.server.recording.library import RecordingNotFound as RecordingNotFound
from telerobot.server.recording.writer import CHUNK_BYTES, describe, serve_file

log = logging.getLogger(__name__)

MAX_QUEUE = 50_000  # messages waiting for the writer (≈ 30 s of 1 kHz force + the rest)
MAX_NAME = 64  # characters of the operator's name kept in the file name
MAX_LISTED = 200  # recordings the list shows (newest first)
MAX_EPISODES = 10_000  # per recording
MAX_TEXT = 2000  # characters of an episode's task or notes
BATCH_S = 0.02  # what has queued goes to the writer process this often
CLOSE_TIMEOUT_S = 60.0  # the writer's index and summary (a long recording: seconds)
MAX_BYTES = 4 * 1024**3  # a recording's file stops here (the setting recording_max_bytes)
MIN_FREE_BYTES = 256 * 1024**2  # …and below this much free space (recording_min_free_bytes)
SPACE_CHECK_S = 0.5  # the writer's progress and the disk's free space are checked this often
# An episode opened before the recording's first video frame waits for it this long at
# most (the worker's tap starts on a key frame it asks for: 1–3 s here, more under load),
# so the episode starts with a picture and the export need not cut it.
FIRST_FRAME_WAIT_S = 20.0
# Stopping waits this long at most for the video frames captured before the stop (they
# come ~0.1 s behind, through the worker's encoder and pipe): else an episode ended just
# before the stop lost its last frames, and the export cut its end.
LAST_FRAME_WAIT_S = 2.0


class RecordingError(TelerobotError):
    code = "recording"
    http_status = 409


class RecordingNoSpace(RecordingError):
    code = "recording_no_space"
    http_status = 507


@dataclass(frozen=True)
class RecordingEvent:
    kind: str  # "started" or "stopped"
    name: str
    file: str
    reason: str = ""


@dataclass
class EpisodeInfo:
    episode: int
    task: str
    started: float  # server clock
    ended: float | None = None
    success: bool | None = None
    notes: str = ""


@dataclass
class _Active:
    name: str
    path: Path
    started_t: float
    started_wall: str
    queue: queue.Queue[tuple[str, int, float, Any] | None]
    process: multiprocessing.process.BaseProcess
    conn: Connection
    thread: threading.Thread | None = None
    dropped: dict[str, int] = field(default_factory=dict)
    episodes: list[EpisodeInfo] = field(default_factory=list)
    bytes: int = 0
    messages: int = 0
    failed: str | None = None  # why the writer ended on its own
    stopping: bool = False
    reason: str = ""
    done: threading.Event = field(default_factory=threading.Event)
    closed: bool = False  # the writer wrote the summary
    counts: dict[str, int] = field(default_factory=dict)  # per topic, from the writer
    metadata: dict[str, str] | None = None  # as written at close
    robot_model: str = ""  # the arm model recorded (its /settings'), "" if not known
    # Set when the first /video/stereo message is queued (a decodable key frame).
    first_frame: threading.Event = field(default_factory=threading.Event)
    last_frame_wall: float = 0.0  # the capture time (wall, s) of the newest frame queued


def recorded_model(settings: dict[str, Any]) -> str:
    """The arm model a recording's settings say it was made with, for its list entry:
    the model's name (``so101``), of several arms each different one joined by ``+``
    (``so101+puma560``), "" if not said."""
    models = list(dict.fromkeys(arm.model for arm in recorded_arms(settings) if arm.model))
    return "+".join(models)


def _free_bytes(folder: Path) -> int:
    return shutil.disk_usage(folder).free


def size_text(n: float) -> str:
    """Bytes for a person: ``512 B``, ``1.5 MiB``, ``4.0 GiB``."""
    if abs(n) < 1024:
        return f"{n:.0f} B"
    for unit in ("KiB", "MiB", "GiB"):
        n /= 1024
        if abs(n) < 1024 or unit == "GiB":
            break
    return f"{n:.1f} {unit}"


def file_name(name: str, wall: dt.datetime) -> str:
    clean = re.sub(r"[^A-Za-z0-9_-]", "", name.replace(" ", "_"))[:MAX_NAME] or "recording"
    return f"{wall.strftime('%Y%m%d-%H%M%S')}-{clean}.mcap"


class Recorder:
    def __init__(
        self,
        folder: Path,
        clock: Clock,
        *,
        wall_ns: Callable[[], int] = time.time_ns,
        max_queue: int = MAX_QUEUE,
        max_listed: int = MAX_LISTED,
        chunk_bytes: int = CHUNK_BYTES,
        max_bytes: int = MAX_BYTES,
        min_free_bytes: int = MIN_FREE_BYTES,
        free_bytes: Callable[[Path], int] = _free_bytes,
    ) -> None:
        self.folder = folder
        self.clock = clock
        self.wall_ns = wall_ns
        self.max_queue = max_queue
        self.max_listed = max_listed
        self.chunk_bytes = chunk_bytes
        self.max_bytes = max_bytes
        self.min_free_bytes = min_free_bytes
        self.free_bytes = free_bytes
        # The read side: ids, the list (from an index), the review's reads
        self.library = RecordingLibrary(folder, active=self.status)
        self.library.budgets.clock = clock.now
        self.events: Event[RecordingEvent] = Event("recording")
        # What is in force when a recording starts (calibration, settings, transforms):
        # set by whoever knows (services), called on the event loop.
        self.snapshot: Callable[[], list[tuple[str, dict[str, Any]]]] = list
        self._active: _Active | None = None
        self._drop_lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        # A video tap follows the recordings (recording/video.py's follow_recorder):
        # their first frame is worth an episode's waiting for.
        self.expects_video = False

    # ------------------------------------------------------------ the hot path
    def log(self, topic: str, payload: dict[str, Any] | bytes, t: float | None = None) -> None:
        """Queue one message for the active recording (nothing if none); never blocks,
        never raises. ``t``: the server clock (now if None)."""
        active = self._active
        if active is None or active.failed is not None or active.stopping:
            return
        if topic == ch.VIDEO and isinstance(payload, dict):
            stamp = payload.get("timestamp") or {}
            active.last_frame_wall = stamp.get("sec", 0) + stamp.get("nsec", 0) / 1e9
            active.first_frame.set()
        try:
            active.queue.put_nowait(
                (topic, self.wall_ns(), self.clock.now() if t is None else t, payload)
            )
        except queue.Full:
            with self._drop_lock:
                active.dropped[topic] = active.dropped.get(topic, 0) + 1

    # ------------------------------------------------------------ control
    @property
    def active(self) -> bool:
        return self._active is not None

    def start(self, name: str) -> Path:
        """Open a new recording (on the event loop); one at a time."""
        if self._active is not None:
            raise RecordingError(f"already recording {self._active.path.name!r}: stop it first")
        self._loop = asyncio.get_running_loop()
        wall = dt.datetime.fromtimestamp(self.wall_ns() / 1e9, dt.UTC)
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            free = self.free_bytes(self.folder)
            if free < self.min_free_bytes:
                reason = (
                    f"the disk is nearly full: {size_text(free)} free in {self.folder}, a"
                    f" recording needs {size_text(self.min_free_bytes)}"
                    " (setting recording_min_free_bytes)"
                )
                self.events.emit(RecordingEvent("stopped", name, "", reason))
                raise RecordingNoSpace(f"the recording cannot start: {reason}")
            path = self.folder / file_name(name, wall)
            n = 1
            while path.exists():
                n += 1
                path = self.folder / file_name(f"{name}-{n}", wall)
            open(path, "xb").close()  # the name is ours (the writer process fills it)
        except OSError as exc:
            reason = f"cannot write in {self.folder}: {exc.strerror or exc}"
            self.events.emit(RecordingEvent("stopped", name, "", reason))
            raise RecordingError(f"the recording cannot start: {reason}") from None
        # A fresh process (spawned: it shares no lock with this one's threads).
        ctx = multiprocessing.get_context("spawn")
        ours, theirs = ctx.Pipe()
        process = ctx.Process(
            target=serve_file,
            args=(theirs, str(path), self.chunk_bytes),
            name=f"recorder {path.name}",
            daemon=True,
        )
        try:
            process.start()
        except OSError as exc:  # no process could be started (out of memory or pids)
            path.unlink(missing_ok=True)
            ours.close()
            raise RecordingError(f"the recording cannot start: {describe(exc)}") from None
        finally:
            theirs.close()
        active = _Active(
            name=name[:MAX_NAME],
            path=path,
            started_t=self.clock.now(),
            started_wall=wall.isoformat(),
            queue=queue.Queue(self.max_queue),
            process=process,
            conn=ours,
        )
        self._active = active
        for topic, payload in self.snapshot():
            if topic == "/settings" and isinstance(payload, dict):
                active.robot_model = recorded_model(payload)
            self.log(topic, payload)
        active.thread = threading.Thread(
            target=self._forward, args=(active,), name=f"recorder {path.name}", daemon=True
        )
        active.thread.start()
        log.info("recording to %s", path)
        self.events.emit(RecordingEvent("started", active.name, path.name))
        return path

    async def stop(self, reason: str = "stopped by the operator") -> Path:
        """Finish the active recording: the writer drains its queue and writes the
        summary (the file is complete when this returns)."""
        active = self._active
        if active is None:
            raise RecordingError("nothing is being recorded")
        if not active.stopping:
            await self._until_frames_before_now(active)
            active.reason = reason
            active.stopping = True
            with contextlib.suppress(queue.Full):
                active.queue.put_nowait(None)  # else the writer sees `stopping` on a timeout
        await asyncio.to_thread(active.done.wait)
        self._ended(active)
        return active.path

    async def _until_frames_before_now(self, active: _Active) -> None:
        """The frames captured until now, which reach the recorder ~0.1 s later, are in
        the recording before it closes (LAST_FRAME_WAIT_S at most; only while its video
        flows)."""
        if not (self.expects_video and active.first_frame.is_set()):
            return
        now = self.wall_ns() / 1e9
        deadline = time.monotonic() + LAST_FRAME_WAIT_S
        while active.last_frame_wall < now and time.monotonic() < deadline:
            if active.failed is not None:
                return
            await asyncio.sleep(0.02)

    def _ended(self, active: _Active) -> None:
        """On the event loop, once the writer is done (stopped, or failed on its own)."""
        if self._active is not active:
            return
        self._active = None
        reason = active.failed or active.reason
        if active.failed:
            log.error("recording %s stopped: %s", active.path.name, active.failed)
        self.events.emit(RecordingEvent("stopped", active.name, active.path.name, reason))

    # ------------------------------------------------------------ episodes
    def episode_start(self, task: str = "") -> EpisodeInfo:
        active = self._need()
        if active.episodes and active.episodes[-1].ended is None:
            self.episode_end()
        if len(active.episodes) >= MAX_EPISODES:
            raise RecordingError(f"a recording holds at most {MAX_EPISODES} episodes")
        ep = EpisodeInfo(len(active.episodes), task[:MAX_TEXT], self.clock.now())
        active.episodes.append(ep)
        self._log_episode("start", ep)
        return ep

    async def episode_start_with_video(
        self, task: str = "", wait_s: float = FIRST_FRAME_WAIT_S
    ) -> EpisodeInfo:
        """``episode_start``, once the recording has its first video frame (at most
        ``wait_s`` later): an episode opened as the recording starts would otherwise begin
        seconds before its picture, and the export would start it there. Without video
        (none expected, or none within ``wait_s``) it starts at once, as before."""
        active = self._need()
        if self.expects_video and not active.first_frame.is_set():
            got = await asyncio.to_thread(active.first_frame.wait, wait_s)
            if not got:
                log.warning("an episode started without video: none came in %.0f s", wait_s)
        return self.episode_start(task)

    def episode_end(self, success: bool | None = None, notes: str | None = None) -> EpisodeInfo:
        active = self._need()
        if not active.episodes or active.episodes[-1].ended is not None:
            raise RecordingError("no episode is open: start one first")
        ep = active.episodes[-1]
        ep.ended = self.clock.now()
        if success is not None:
            ep.success = success
        if notes is not None:
            ep.notes = notes[:MAX_TEXT]
        self._log_episode("end", ep)
        return ep

    def label(
        self,
        episode: int,
        *,
        task: str | None = None,
        success: bool | None = None,
        notes: str | None = None,
    ) -> EpisodeInfo:
        active = self._need()
        if not 0 <= episode < len(active.episodes):
            raise InvalidCommand(f"no episode {episode} in this recording")
        ep = active.episodes[episode]
        if task is not None:
            ep.task = task[:MAX_TEXT]
        if success is not None:
            ep.success = success
        if notes is not None:
            ep.notes = notes[:MAX_TEXT]
        self._log_episode("label", ep)
        return ep

    def _log_episode(self, event: str, ep: EpisodeInfo) -> None:
        self.log(
            ch.EPISODES,
            {
                "event": event,
                "episode": ep.episode,
                "task": ep.task,
                "success": ep.success,
                "notes": ep.notes,
            },
        )

    def _need(self) -> _Active:
        if self._active is None:
            raise RecordingError("nothing is being recorded: start a recording first")
        return self._active

    # ------------------------------------------------------------ status, files
    def status(self) -> dict[str, Any] | None:
        a = self._active
        if a is None:
            return None
        return {
            "name": a.name,
            "file": a.path.name,
            "started": a.started_wall,
            "elapsed_s": self.clock.now() - a.started_t,
            "bytes": a.bytes,
            "messages": a.messages,
            "queued": a.queue.qsize(),
            "dropped": dict(a.dropped),
            "episodes": [vars(e).copy() for e in a.episodes],
        }

    def path_of(self, file: str) -> Path:
        """A recording's file, to be read: 404 if there is none, 409 for the one being
        written (its file has no summary yet and grows under the reader), 422 for an id
        longer than a file name may be (before the disk is touched)."""
        return self.library.path(file)

    def delete(self, file: str) -> None:
        path = self.library.path(file, allow_active=True)
        if self._active is not None and self._active.path == path:
            raise RecordingError(f"{file!r} is being recorded: stop it first")
        path.unlink()
        self.library.forget(path.name)

    def listing(self, limit: int | None = None, offset: int = 0) -> list[dict[str, Any]]:
        """The newest ``max_listed`` recordings (or ``limit`` from ``offset``): file,
        name, size, duration, episodes, complete, stop_reason, active; from the index,
        summarising here what is not in it (the server's API lists with
        ``library.listing``, which never parses in its own process)."""
        entries, _total = self.library.listing_now(limit or self.max_listed, offset)
        return entries

    # ------------------------------------------------------------ the forwarding thread
    def _forward(self, a: _Active) -> None:
        """Wakes every ``BATCH_S`` and sends what has queued to the writer process as one
        message (one pickle, one pipe write; no wake-up per message: a thread switch
        each, on a 2-core machine, showed in the loop's latency). A writer that falls
        behind fills the pipe and then this queue, which drops and counts: the callers
        of ``log`` never wait."""
        next_check = time.monotonic()
        try:
            while True:
                time.sleep(BATCH_S)
                batch = []
                while True:
                    try:
                        item = a.queue.get_nowait()
                    except queue.Empty:
                        break
                    if item is not None:
                        batch.append(item)
                if batch:
                    a.conn.send(("batch", batch))
                self._answers(a)
                if not a.stopping and time.monotonic() >= next_check:
                    next_check = time.monotonic() + SPACE_CHECK_S
                    self._check_space(a)
                if a.stopping and a.queue.empty():
                    break
            a.metadata = self._metadata(a)
            a.conn.send(("close", a.metadata))
            deadline = time.monotonic() + CLOSE_TIMEOUT_S
            while not a.closed:  # progress said before it may come first
                if not a.conn.poll(max(0.0, deadline - time.monotonic())):
                    raise _WriterGone(f"did not finish the file within {CLOSE_TIMEOUT_S:.0f} s")
                self._answers(a)
        except _WriterGone as exc:
            a.failed = f"the recording's writer failed: {exc}"
        except (EOFError, OSError) as exc:  # the pipe broke: the writer process is gone
            a.failed = f"the recording's writer failed: {self._writer_end(a, exc)}"
        except BaseException as exc:  # a bug here
            a.failed = f"the recording's writer failed: {describe(exc)}"
        finally:
            with contextlib.suppress(OSError):
                a.conn.close()
            a.process.join(5)
            if a.process.is_alive():
                a.process.kill()
            a.bytes = _size(a.path)
            self._keep_in_index(a)
            a.done.set()
            loop = self._loop
            if loop is not None and not loop.is_closed():
                with contextlib.suppress(RuntimeError):
                    loop.call_soon_threadsafe(self._ended, a)

    @staticmethod
    def _answers(a: _Active) -> None:
        """Take in what the writer process said: progress, or why it stopped."""
        while a.conn.poll():
            answer = a.conn.recv()
            if answer[0] == "failed":
                raise _WriterGone(answer[1])
            a.bytes, a.messages = answer[1], answer[2]
            if answer[0] == "closed":
                a.closed = True
                a.counts = dict(answer[3]) if len(answer) > 3 else {}

    def _check_space(self, a: _Active) -> None:
        """Stop (the file closed whole, the reason kept) at the size cap, or before the
        disk is full (a write that fails there would leave a file without a summary)."""
        if a.bytes >= self.max_bytes:
            why = (
                f"size cap reached: {size_text(a.bytes)}, at most"
                f" {size_text(self.max_bytes)} (setting recording_max_bytes)"
            )
        else:
            try:
                free = self.free_bytes(self.folder)
            except OSError:
                return
            if free >= self.min_free_bytes:
                return
            why = (
                f"the disk is nearly full: {size_text(free)} free, a recording stops below"
                f" {size_text(self.min_free_bytes)} (setting recording_min_free_bytes)"
            )
        log.warning("recording %s stops: %s", a.path.name, why)
        a.reason = why
        a.stopping = True

    def _keep_in_index(self, a: _Active) -> None:
        """What the list shows of this recording, with why it stopped (kept even when
        the writer failed and the file has no summary to say it)."""
        try:
            meta = a.metadata or self._metadata(a)
            self.library.closed(
                a.path, meta, a.counts, complete=a.closed, reason=a.failed or a.reason
            )
        except Exception:  # the index is a convenience: the recording is on disk
            log.exception("recording %s: its index entry was not written", a.path.name)

    @staticmethod
    def _writer_end(a: _Active, exc: BaseException) -> str:
        """Why the pipe broke: what the writer said before it ended, or how it ended."""
        try:
            Recorder._answers(a)
        except _WriterGone as said:
            return str(said)
        except (EOFError, OSError):
            pass
        a.process.join(1)
        code = a.process.exitcode
        if code is not None and code < 0:
            return f"its process was killed (signal {-code})"
        if code is not None:
            return f"its process ended (exit code {code})"
        return describe(exc)

    def _metadata(self, a: _Active) -> dict[str, str]:
        meta = {
            "name": a.name,
            "started": a.started_wall,
            "stopped": dt.datetime.fromtimestamp(self.wall_ns() / 1e9, dt.UTC).isoformat(),
            "duration_s": f"{self.clock.now() - a.started_t:.3f}",
            "stop_reason": a.reason,
            "episodes": json.dumps([vars(e) for e in a.episodes]),
        }
        if a.robot_model:  # the list says it (a task repeats only this arm model's)
            meta["robot_model"] = a.robot_model
        with self._drop_lock:
            for topic, n in a.dropped.items():
                meta[f"dropped.{topic}"] = str(n)
        return meta


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


class _WriterGone(Exception):
    """The writer process stopped and said why (or did not answer)."""


# ---------------------------------------------------------------- taps
def _quat(R: np.ndarray) -> dict[str, float]:
    """Rotation matrix → quaternion (x, y, z, w)."""
    import pinocchio as pin

    x, y, z, w = pin.Quaternion(np.asarray(R, dtype=float)).coeffs().tolist()
    return {"x": x, "y": y, "z": z, "w": w}


def transform(
    parent: str, child: str, R: np.ndarray, p: np.ndarray, wall_ns: int
) -> dict[str, Any]:
    """One ``foxglove.FrameTransform``: ``child``'s pose in ``parent``."""
    return {
        "timestamp": {"sec": wall_ns // 1_000_000_000, "nsec": wall_ns % 1_000_000_000},
        "parent_frame_id": parent,
        "child_frame_id": child,
        "translation": dict(zip("xyz", np.asarray(p, dtype=float).tolist(), strict=True)),
        "rotation": _quat(R),
    }


def command_payload(r: CommandReport) -> dict[str, Any]:
    return {
        "t": r.t,
        "source": r.source,
        "client_id": r.client_id or "",
        "client": r.client,
        "kind": r.kind,
        "args": r.args,
        "accepted": r.error is None,
        "reason": str(r.error) if r.error is not None else "",
        "code": r.error.code if r.error is not None else "",
        "target_joints": r.target,
        "lease_holder": r.lease_holder,
        "role": r.role,
        "autonomy": r.autonomy,
        "age_ms": r.age * 1000.0 if r.age is not None else None,
    }


class RecordingTaps:
    """The recorder's subscriptions: force samples (on the sensor's thread), the
    state at the state rate (its own task), every command and safety change.

    On a server with two arms or more (the DecisionServer's ``arms``), each arm's state
    and forces go to its own channels (``/arms/<name>/state``, ``/arms/<name>/force``),
    ``/tf`` places each arm's base and tool (``<name>/base``, ``<name>/tool``) in the
    workcell's ``base``, and ``/arms`` says the arms once as a recording starts
    (docs/recording.md). One arm: on the channels as before (``/robot/state``, ``/force``)."""

    def __init__(
        self,
        recorder: Recorder,
        *,
        decision: DecisionServer,
        clock: Clock,
        state_period: float,
        tasks: Event[Any] | None = None,
    ) -> None:
        self.recorder = recorder
        self.tasks = tasks  # the task runner's changes: what a task did is recorded too
        self.decision = decision
        self.clock = clock
        self.state_period = state_period
        self._unsubscribe: list[Callable[[], None]] = []
        self._task: asyncio.Task[None] | None = None

    @property
    def arms(self) -> list[ArmGuard]:
        """The arms recorded on channels of their own (none on a one-arm server)."""
        arms = self.decision.arms
        return list(arms) if len(arms) > 1 else []

    def start(self) -> None:
        rec = self.recorder
        arms = self.arms
        sensors: list[tuple[ForceSensor | None, str, str | None]] = [
            (g.force, ch.arm_topic(g.name, ch.ARM_FORCE), g.name) for g in arms
        ] or [(self.decision.arms[0].force, ch.FORCE, None)]  # the only arm
        for sensor, topic, arm in sensors:
            if sensor is not None:
                self._unsubscribe.append(sensor.subscribe(self._force_tap(topic, arm)))
        if arms:
            self._unsubscribe.append(self.recorder.events.subscribe(self._on_recording))
        self._unsubscribe.append(
            self.decision.events.command.subscribe(
                lambda r: rec.log(ch.COMMANDS, command_payload(r), r.t)
            )
        )
        self._unsubscribe.append(self.decision.events.safety_changed.subscribe(self._on_safety))
        self._unsubscribe.append(
            self.decision.events.autonomy_changed.subscribe(
                lambda a: rec.log(ch.AUTONOMY, a.as_dict(), a.t)
            )
        )
        if self.tasks is not None:
            self._unsubscribe.append(self.tasks.subscribe(self._on_task))
        self._task = asyncio.get_running_loop().create_task(self._states(), name="record-state")

    def _force_tap(self, topic: str, arm: str | None) -> Callable[[ForceSample], None]:
        rec = self.recorder
        if arm is None:

            def on_sample(s: ForceSample) -> None:  # the sensor's thread: one queue put
                if rec._active is not None:
                    rec.log(topic, {"seq": s.seq, "sensor_time": s.time, "values": list(s.values)})

            return on_sample

        def on_arm_sample(s: ForceSample) -> None:
            if rec._active is not None:
                rec.log(
                    topic,
                    {"arm": arm, "seq": s.seq, "sensor_time": s.time, "values": list(s.values)},
                )

        return on_arm_sample

    def _on_recording(self, e: RecordingEvent) -> None:
        """A recording started: which arms it holds, and where each stands (once)."""
        if e.kind != "started":
            return
        arms = []
        for g in self.arms:
            arms.append(
                {
                    "name": g.name,
                    "index": g.index,
                    "model": g.robot.model.name,
                    "dof": g.dof,
                    "joint_names": list(g.kinematics.joint_names),
                    "mount": np.asarray(g.mount, dtype=float).tolist(),
                }
            )
        self.recorder.log(ch.ARMS, {"arms": arms})

    def _on_safety(self, s: SafetyState) -> None:
        payload: dict[str, Any] = {
            "estop": s.estop,
            "estop_reason": s.estop_reason,
            "force_limited": s.force_limited,
            "halted": s.halted,
            "lease_holder": s.lease_holder,
            "lease_holder_name": s.lease_holder_name,
            "lease_note": s.lease_note,
        }
        if self.arms:  # which arm's force limit (a one-arm recording's is as before)
            payload["force_limited_arms"] = list(s.force_limited_arms)
        self.recorder.log(ch.SAFETY, payload)

    def _on_task(self, status: Any) -> None:
        payload = dataclasses.asdict(status)
        payload["state"] = str(getattr(status.state, "value", status.state))
        payload["offset"] = list(payload["offset"])
        if payload.get("arms"):  # a multi-arm task's arms (a one-arm task's are as before)
            payload["arms"] = list(payload["arms"])
        else:
            payload.pop("arms", None)
        self.recorder.log(ch.TASKS, payload)

    def log_state(self) -> None:
        rec = self.recorder
        if self.arms:
            self._log_arm_states()
            return
        robot = self.decision.arms[0].robot  # the only arm
        pose = robot.pose
        rec.log(
            ch.ROBOT_STATE,
            {
                "status": str(robot.status),
                "joints": robot.joints.tolist(),
                "target_joints": robot.target_joints.tolist(),
                "position": pose.position.tolist(),
                "rotation": pose.rotation.ravel().tolist(),
            },
        )
        rec.log(
            ch.TF,
            {
                "transforms": [
                    transform("base", "tool", pose.rotation, pose.position, rec.wall_ns())
                ]
            },
        )

    def _log_arm_states(self) -> None:
        """Each arm's state on its channel, and one ``/tf`` placing every arm's base (its
        mount) and tool in the workcell's ``base``."""
        rec = self.recorder
        wall = rec.wall_ns()
        transforms = []
        for g in self.arms:
            robot = g.robot
            pose = robot.pose
            rec.log(
                ch.arm_topic(g.name, ch.ARM_STATE),
                {
                    "arm": g.name,
                    "status": str(robot.status),
                    "joints": robot.joints.tolist(),
                    "target_joints": robot.target_joints.tolist(),
                    "position": pose.position.tolist(),
                    "rotation": pose.rotation.ravel().tolist(),
                },
            )
            mount = np.asarray(g.mount, dtype=float)
            transforms.append(
                transform("base", f"{g.name}/base", mount[:3, :3], mount[:3, 3], wall)
            )
            transforms.append(
                transform(f"{g.name}/base", f"{g.name}/tool", pose.rotation, pose.position, wall)
            )
        rec.log(ch.TF, {"transforms": transforms})

    async def _states(self) -> None:
        while True:
            await self.clock.sleep(self.state_period)
            if self.recorder._active is not None:
                try:
                    self.log_state()
                except Exception:  # a recording must never end the robot's loop
                    log.exception("recording the state failed")

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None


def recordings_folder(state: Path) -> Path:
    return state / "recordings"


__all__ = ["Recorder", "RecordingError", "RecordingEvent", "RecordingTaps"]
