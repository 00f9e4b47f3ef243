"""Encode once, send to every peer: each WebRTC video track reads the same encoded
packets (aiortc packetises a pre-encoded ``av.Packet`` without re-encoding).

Each track has a short queue. A viewer that falls behind loses its queue and waits
for the next keyframe (which it asks for), rather than decoding a broken stream or
replaying stale frames.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Callable

import av
from aiortc import MediaStreamTrack

from backend.media.encoder import EncodedFrame

log = logging.getLogger(__name__)

TRACK_QUEUE = 8  # frames a viewer may lag before it is resynchronised on a keyframe


class SharedVideoTrack(MediaStreamTrack):
    kind = "video"

    def __init__(
        self, request_keyframe: Callable[[], None], on_close: Callable[[SharedVideoTrack], None]
    ) -> None:
        super().__init__()
        self._queue: deque[EncodedFrame] = deque()
        self._ready = asyncio.Event()
        self._request_keyframe = request_keyframe
        self._on_close = on_close
        self._waiting_for_keyframe = True
        self.sent_frames = 0
        self.sent_bytes = 0
        self.resyncs = 0

    def push(self, frame: EncodedFrame) -> None:
        if self._waiting_for_keyframe:
            if not frame.keyframe:
                return
            self._waiting_for_keyframe = False
        if len(self._queue) >= TRACK_QUEUE:
            self._queue.clear()
            self._waiting_for_keyframe = True
            self.resyncs += 1
            self._request_keyframe()
            return
        self._queue.append(frame)
        self._ready.set()

    def keyframe_requested(self) -> None:
        """The remote decoder asked (PLI/FIR): forward it to the shared encoder."""
        self._request_keyframe()

    async def recv(self) -> av.Packet:  # type: ignore[type-arg]
        while not self._queue:
            self._ready.clear()
            await self._ready.wait()
            if self.readyState != "live":
                raise asyncio.CancelledError
        frame = self._queue.popleft()
        self.sent_frames += 1
        self.sent_bytes += frame.size
        packet: av.Packet = frame.packet  # type: ignore[type-arg]
        return packet

    def stop(self) -> None:
        super().stop()
        self._ready.set()
        self._on_close(self)


class Broadcaster:
    """The set of live tracks; ``publish`` hands one encoded frame to all of them."""

    def __init__(self, request_keyframe: Callable[[], None]) -> None:
        self._request_keyframe = request_keyframe
        self.tracks: set[SharedVideoTrack] = set()

    def new_track(self) -> SharedVideoTrack:
        track = SharedVideoTrack(self._request_keyframe, self.tracks.discard)
        self.tracks.add(track)
        self._request_keyframe()  # a new viewer starts on a keyframe
        return track

    @property
    def viewers(self) -> int:
        return len(self.tracks)

    def publish(self, frame: EncodedFrame) -> None:
        for track in list(self.tracks):
            track.push(frame)
