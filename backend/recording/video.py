"""The stereo video into the recording: the same H.264 packets WebRTC sends (the one
encode, tapped where the fan-out gets them in the media worker), logged on
``/video/stereo`` as ``foxglove.CompressedVideo`` (docs/recording.md).

The worker's end (``backend/media/tap.py``) starts on a keyframe it asks for, hands
packets over through a bounded queue (dropped and counted, never blocking the encoder)
and a pipe of their own; ``VideoTap`` here, on the server, turns each into the
message: ``timestamp`` the capture time on the wall clock, ``data`` the Annex B
access unit (x264 repeats SPS/PPS before every keyframe, so the first message, a
keyframe, starts with them).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Protocol

import av

from telerobot.server.media.encoder import VIDEO_CLOCK
from telerobot.server.media.tap import unpack

log = logging.getLogger(__name__)

VIDEO_TOPIC = "/video/stereo"
FRAME_ID = "stereo"

NAL_SPS, NAL_PPS, NAL_IDR = 7, 8, 5


def nal_types(annex_b: bytes) -> list[int]:
    """The NAL unit types of an Annex B access unit, in order."""
    types = []
    i = annex_b.find(b"\x00\x00\x01")
    while i >= 0 and i + 3 < len(annex_b):
        types.append(annex_b[i + 3] & 0x1F)
        i = annex_b.find(b"\x00\x00\x01", i + 3)
    return types


def starts_decodable(annex_b: bytes) -> bool:
    """An IDR preceded by its SPS and PPS: a decoder can start here."""
    types = nal_types(annex_b)
    return (
        NAL_IDR in types
        and NAL_SPS in types[: types.index(NAL_IDR)]
        and (NAL_PPS in types[: types.index(NAL_IDR)])
    )


class VideoSource(Protocol):
    """What the tap needs of the media side (``MediaSupervisor``)."""

    async def record_video(self, sink: Callable[[bytes], None] | None) -> dict[str, Any]: ...


LogFn = Callable[[str, dict[str, Any]], object]


@dataclass
class VideoTapCounts:
    packets: int = 0  # logged
    bytes: int = 0
    keyframes: int = 0
    skipped: int = 0  # arrived before the first decodable keyframe
    worker_dropped: int = 0  # the worker's queue dropped them (the server fell behind)


def capture_wall_time(capture_monotonic: float) -> float:
    """A monotonic capture time on the wall clock (both clocks read now)."""
    return capture_monotonic + (time.time() - time.monotonic())


class VideoTap:
    """``start(log)`` when a recording starts, ``stop()`` when it stops. ``log`` is the
    recorder's ``log(topic, payload)`` (non-blocking: it drops and counts)."""

    def __init__(self, media: VideoSource) -> None:
        self.media = media
        self._log: LogFn | None = None
        self._lock = threading.Lock()
        self._started = False  # the first decodable keyframe has been logged
        self.counts = VideoTapCounts()

    @property
    def active(self) -> bool:
        return self._log is not None

    async def start(self, log_fn: LogFn) -> None:
        with self._lock:
            self._log = log_fn
            self._started = False
            self.counts = VideoTapCounts()
        await self.media.record_video(self.on_packet)

    async def stop(self) -> VideoTapCounts:
        try:
            reply = await self.media.record_video(None)
            self.counts.worker_dropped = max(self.counts.worker_dropped, reply.get("dropped", 0))
        finally:
            with self._lock:
                self._log = None
        return self.counts

    def on_packet(self, message: bytes) -> None:
        """One packet from the worker (the supervisor's reader thread)."""
        packet = unpack(message)
        with self._lock:
            log_fn = self._log
            if log_fn is None:
                return
            if not self._started:
                if not (packet.keyframe and starts_decodable(packet.data)):
                    self.counts.skipped += 1
                    return
                self._started = True
            c = self.counts
            c.packets += 1
            c.bytes += len(packet.data)
            c.keyframes += packet.keyframe
            c.worker_dropped = packet.dropped
        wall = capture_wall_time(packet.capture_time)
        sec = int(wall)
        log_fn(
            VIDEO_TOPIC,
            {
                "timestamp": {"sec": sec, "nsec": int((wall - sec) * 1e9)},
                "frame_id": FRAME_ID,
                "format": "h264",
                "data": packet.data,
            },
        )


class NoVideo(ValueError):
    """The recording holds no video."""


def remux_mp4(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> dict[str, float | int]:
    """The recording's ``/video/stereo`` packets into an MP4 (no re-encode: the same
    H.264 access units, timed by their capture times), for a ``<video>`` element that
    plays and seeks natively. Returns ``start`` (the first frame's capture time, wall
    clock s: the MP4's time 0), ``frames``, ``width``, ``height``. Written beside
    ``dst`` and moved into place, so a reader never sees half a file."""
    from telerobot.server.recording.reader import read

    times: list[float] = []
    dst = Path(dst)
    with tempfile.TemporaryDirectory(dir=dst.parent) as tmp:
        annex_b = Path(tmp) / "video.h264"
        with open(annex_b, "wb") as f:
            for _topic, _log_ns, m in read(src, [VIDEO_TOPIC]):
                ts = m.get("timestamp") or {}
                times.append(ts.get("sec", 0) + ts.get("nsec", 0) / 1e9)
                f.write(m["data"])
        if not times:
            raise NoVideo(f"{Path(src).name} holds no video")
        t0 = times[0]
        part = Path(tmp) / "video.mp4"
        with av.open(str(annex_b), format="h264") as inp:
            in_stream = inp.streams.video[0]
            width, height = in_stream.codec_context.width, in_stream.codec_context.height
            with av.open(str(part), "w", format="mp4", options={"movflags": "+faststart"}) as out:
                ost = out.add_stream_from_template(in_stream)
                ost.time_base = Fraction(1, VIDEO_CLOCK)
                last, n = -1, 0
                for packet in inp.demux(in_stream):
                    if packet.size == 0:
                        continue
                    # Capture time where the packet has one; a frame beyond (the parser
                    # split differently) one frame interval on.
                    t = times[n] if n < len(times) else times[-1] + (n - len(times) + 1) / 30
                    pts = max(last + 1, round((t - t0) * VIDEO_CLOCK))
                    packet.pts = packet.dts = last = pts
                    packet.time_base = ost.time_base
                    packet.stream = ost
                    out.mux(packet)
                    n += 1
        os.replace(part, dst)
    return {"start": t0, "frames": n, "width": width, "height": height}


class _RecordingEvent(Protocol):
    @property
    def kind(self) -> str: ...


class _Events(Protocol):
    def subscribe(self, handler: Callable[[Any], None]) -> Callable[[], None]: ...


class _Recorder(Protocol):
    expects_video: bool

    @property
    def events(self) -> _Events: ...

    def log(self, topic: str, payload: dict[str, Any], t: float | None = None) -> None: ...


def follow_recorder(tap: VideoTap, recorder: _Recorder) -> Callable[[], None]:
    """Start the tap when a recording starts and stop it when it stops (in order, on
    the event loop that emits them). Returns the unsubscribe."""
    last: list[asyncio.Task[Any]] = []
    recorder.expects_video = True  # an episode waits for the recording's first frame

    async def after(previous: asyncio.Task[Any] | None, start: bool) -> None:
        if previous is not None:
            with contextlib.suppress(Exception):
                await previous
        try:
            if start:
                await tap.start(recorder.log)
            elif tap.active:
                counts = await tap.stop()
                log.info("recording's video: %s", counts)
        except Exception as exc:  # the media worker down: the recording goes on without
            log.error("the recording's video could not %s: %s", "start" if start else "stop", exc)

    def on_event(event: _RecordingEvent) -> None:
        if event.kind not in ("started", "stopped"):
            return
        previous = last[0] if last else None
        task = asyncio.get_running_loop().create_task(
            after(previous, event.kind == "started"), name=f"recording-video-{event.kind}"
        )
        last[:] = [task]

    return recorder.events.subscribe(on_event)
