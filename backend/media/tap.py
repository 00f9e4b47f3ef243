"""The recording's tap on the encoded video, the media worker's end: every H.264 packet
the fan-out gets (the one encode) goes, as the same bytes, over a pipe of its own to the
server, where ``telerobot.server.recording.video.VideoTap`` logs it.

The encoder never waits for the server: packets go into a bounded queue that a thread
of its own drains into the pipe. When the queue is full its packets are dropped and
counted, and the next packet handed over is a keyframe (one is asked for), so the
recording loses a stretch of video but never holds a frame it cannot decode.

The encoder makes keyframes only when asked (backend/media/encoder.py), so while a
recording runs the tap asks for one every ``RECORDING_KEYFRAME_S`` of capture time: a
player seeks to the keyframe before a point and decodes from there.

Wire format, one ``send_bytes`` per packet: ``HEADER`` (keyframe, capture time on the
monotonic clock, frame seq, packets dropped so far) then the Annex B access unit.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from telerobot.server.media.encoder import EncodedFrame

log = logging.getLogger(__name__)

HEADER = struct.Struct("<?dqQ")
# Packets the worker holds for the server: ~2 s at 60 fps (4 s at 30). A keyframe is
# ~100 kB at the default 8 Mbit/s, a frame ~17 kB at 60 fps, so the queue holds at most
# a few MB.
TAP_QUEUE = 128
RECORDING_KEYFRAME_S = 2.0  # the longest stretch a player must decode to seek


@dataclass(frozen=True)
class TappedPacket:
    keyframe: bool
    capture_time: float  # monotonic clock (the same on both sides of the pipe)
    seq: int
    dropped: int  # packets the worker's queue dropped so far in this recording
    data: bytes  # Annex B


def pack(keyframe: bool, capture_time: float, seq: int, dropped: int, data: bytes) -> bytes:
    return HEADER.pack(keyframe, capture_time, seq, dropped) + data


def unpack(message: bytes) -> TappedPacket:
    keyframe, t, seq, dropped = HEADER.unpack_from(message)
    return TappedPacket(keyframe, t, seq, dropped, message[HEADER.size :])


class PacketPipe:
    """``push`` (on the pipeline's loop) never blocks; one thread, for the worker's life,
    sends what it holds (one sender, so messages never interleave on the pipe).
    ``restart`` begins a recording: counters from zero, the next keyframe first."""

    def __init__(
        self,
        send: Callable[[bytes], Any],
        request_keyframe: Callable[[], None],
        limit: int = TAP_QUEUE,
    ) -> None:
        self._send = send
        self._request_keyframe = request_keyframe
        self.limit = limit
        self._queue: deque[bytes] = deque()
        self._cond = threading.Condition()
        self._closed = False
        self._waiting_for_keyframe = True
        self._last_keyframe: float | None = None  # capture time; None: none recorded yet
        self.sent = 0
        self.dropped = 0
        self._thread = threading.Thread(target=self._drain, name="video-tap", daemon=True)
        self._thread.start()

    def restart(self) -> None:
        with self._cond:
            self._waiting_for_keyframe = True
            self._last_keyframe = None
            self.sent = self.dropped = 0

    def push(self, e: EncodedFrame) -> None:
        if self._waiting_for_keyframe:
            if not e.keyframe:
                return  # a recording starts (and resumes after a drop) on a keyframe
            self._waiting_for_keyframe = False
        if e.keyframe or self._last_keyframe is None:
            self._last_keyframe = e.capture_time
        elif e.capture_time - self._last_keyframe >= RECORDING_KEYFRAME_S:
            self._last_keyframe = e.capture_time  # asked once a stretch (the gate spaces them)
            self._request_keyframe()
        with self._cond:
            if len(self._queue) >= self.limit:
                self.dropped += len(self._queue) + 1
                self._queue.clear()
                self._waiting_for_keyframe = True
                self._request_keyframe()
                log.warning("video tap: the server fell behind; %d packets dropped", self.dropped)
                return
            data = bytes(e.packet)
            self._queue.append(pack(e.keyframe, e.capture_time, e.seq, self.dropped, data))
            self._cond.notify()

    def _drain(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closed:
                    self._cond.wait()
                if not self._queue:
                    return  # closed and drained
                message = self._queue.popleft()
            try:
                self._send(message)
            except (OSError, ValueError):  # the server is gone
                return
            self.sent += 1

    def close(self, timeout: float = 2.0) -> None:
        """Send what is queued (within ``timeout``) and stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout)
