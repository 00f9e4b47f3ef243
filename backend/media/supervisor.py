"""The server's side of the media worker: starts it, restarts it if it dies, forwards
signalling to it, and publishes every arm's state into shared memory for it (one array
per arm, in the server's arm order)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import multiprocessing
import threading
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from telerobot.drivers.base import Robot, TelerobotError
from telerobot.server.media import rpc
from telerobot.server.media.worker import arm_fields, worker_main
from telerobot.server.settings import Settings

log = logging.getLogger(__name__)


class MediaUnavailable(TelerobotError):
    code = "media_unavailable"
    http_status = 503


class MediaRequestFailed(TelerobotError):
    """The media worker refused a request with an error this process has no class for."""

    http_status = 502

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


class MediaSupervisor:
    def __init__(self, settings: Settings, robots: Robot | Sequence[Robot]) -> None:
        """``robots``: every arm's driver, in the settings' arm order (one: that arm)."""
        self.settings = settings
        self.robots = list(robots) if isinstance(robots, Sequence) else [robots]
        self.robot = self.robots[0]
        arms = settings.arm_settings()
        if len(arms) != len(self.robots):
            raise ValueError(
                f"the media worker follows {len(arms)} arms, but was given"
                f" {len(self.robots)} drivers"
            )
        self._ctx = multiprocessing.get_context("spawn")  # never fork a threaded server
        self._arms: list[Any] = [
            self._ctx.Array("d", arm_fields(own.model.dof), lock=True) for _, own in arms
        ]
        self._proc: Any = None
        self._conn: Any = None
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[rpc.Reply]] = {}
        self._ready = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []
        self.restarts = 0
        self.started_at = 0.0
        self._stopping = False
        # The recording's video (backend/recording/video.py): while set, the worker sends
        # every H.264 packet, and this is called with each (on a reader thread of its own,
        # so a megabyte a second never passes through the event loop).
        self._video_sink: Callable[[bytes], None] | None = None

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive() and self._ready.is_set()

    async def start(self) -> None:
        self._publish_arm()
        self._spawn()
        self._tasks = [
            asyncio.create_task(self._publish_loop(), name="media-arm-state"),
            asyncio.create_task(self._watch(), name="media-watchdog"),
        ]

    def _spawn(self) -> None:
        parent, child = self._ctx.Pipe()
        video_in, video_out = self._ctx.Pipe(duplex=False)
        self._conn = parent
        self._ready.clear()
        self._proc = self._ctx.Process(
            target=worker_main,
            # (without the operator token: the worker needs none, and a SecretStr
            # dumps as asterisks, which the worker's settings would refuse)
            args=(
                child,
                self.settings.model_dump_json(exclude={"operator_token"}),
                self._arms,
                video_out,
            ),
            name="telerobot-media",
            daemon=True,
        )
        self._proc.start()
        child.close()
        video_out.close()
        asyncio.get_running_loop().add_reader(parent.fileno(), self._readable)
        threading.Thread(
            target=self._read_video, args=(video_in,), name="media-video-tap", daemon=True
        ).start()

    def _read_video(self, conn: Any) -> None:
        """Until this worker is gone: each packet to the sink, if a recording wants it."""
        with conn:
            while True:
                try:
                    message = conn.recv_bytes()
                except (EOFError, OSError):
                    return
                sink = self._video_sink
                if sink is not None:
                    try:
                        sink(message)
                    except Exception:  # a recording's bug must not end the reader
                        log.exception("the recording's video sink failed")

    async def record_video(self, sink: Callable[[bytes], None] | None) -> dict[str, Any]:
        """Start (a sink) or stop (None) sending the encoded video to ``sink``; the worker
        runs the pipeline while it records, viewers or not, and starts on a keyframe.
        Answers the worker's counts (``sent``, ``dropped``) so far."""
        if sink is not None:
            self._video_sink = sink
            return await self.request(rpc.Record(on=True))
        try:
            return await self.request(rpc.Record(on=False))
        finally:  # packets already on their way still reach the recording
            self._video_sink = None

    def _readable(self) -> None:
        try:
            msg = self._conn.recv()
        except (EOFError, OSError):
            asyncio.get_running_loop().remove_reader(self._conn.fileno())
            return
        if isinstance(msg, rpc.Ready):
            self._ready.set()
            if self._video_sink is not None:  # a worker restarted while recording
                self._conn.send(rpc.Envelope(None, rpc.Record(on=True)))
            return
        assert isinstance(msg, rpc.Reply), msg
        future = self._pending.pop(msg.id, None) if msg.id is not None else None
        if future is not None and not future.done():
            future.set_result(msg)

    def _publish_arm(self) -> None:
        for robot, shared in zip(self.robots, self._arms, strict=True):
            s = robot.snapshot()
            values = [s.time, *s.joints.tolist(), *s.velocities.tolist()]
            with shared.get_lock():
                np.frombuffer(shared.get_obj(), dtype=np.float64)[:] = values

    async def _publish_loop(self) -> None:
        while True:
            await asyncio.sleep(0.01)
            self._publish_arm()

    async def _watch(self) -> None:
        while True:
            await asyncio.sleep(1.0)
            if self._stopping or (self._proc is not None and self._proc.is_alive()):
                continue
            log.error(
                "media worker died (exit code %s); restarting it",
                self._proc.exitcode if self._proc else None,
            )
            for future in self._pending.values():
                if not future.done():
                    future.set_exception(MediaUnavailable("the media worker restarted; try again"))
            self._pending.clear()
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._conn.fileno())
            self.restarts += 1
            self._spawn()

    async def request(self, body: rpc.MediaRequest, timeout: float = 15.0) -> dict[str, Any]:
        """``body`` answered by the worker (its reply's fields), or its error raised as
        the error's own class."""
        op = type(body).__name__
        try:
            await asyncio.wait_for(self._ready.wait(), timeout)
        except TimeoutError:
            raise MediaUnavailable("the media worker is not running (see the server log)") from None
        req_id = next(self._ids)
        future: asyncio.Future[rpc.Reply] = asyncio.get_running_loop().create_future()
        self._pending[req_id] = future
        self._conn.send(rpc.Envelope(req_id, body))
        try:
            reply = await asyncio.wait_for(future, timeout)
        except TimeoutError:
            self._pending.pop(req_id, None)
            raise MediaUnavailable(
                f"the media worker did not answer {op!r} within {timeout:g} s"
            ) from None
        if not reply.ok:
            code, text = reply.code or "media_error", reply.error or "unknown error"
            known = TelerobotError.with_code(code)  # the worker's error, as its own class
            if known is not None and known is not TelerobotError:
                raise known(text)
            raise MediaRequestFailed(code, text)
        return reply.result

    async def stop(self) -> None:
        self._stopping = True
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self._conn is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._conn.fileno())
            with contextlib.suppress(Exception):
                self._conn.send(rpc.Envelope(None, rpc.Shutdown()))
        if self._proc is not None:
            await asyncio.get_running_loop().run_in_executor(None, self._proc.join, 5)
            if self._proc.is_alive():
                self._proc.terminate()
