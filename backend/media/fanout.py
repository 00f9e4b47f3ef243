"""Encode once, send to every peer: each WebRTC video track reads the same encoded
packets (aiortc packetises a pre-encoded ``av.Packet`` without re-encoding).

Each track has a short queue. A viewer that falls behind loses its queue and waits
for the next keyframe (which it asks for), rather than decoding a broken stream or
replaying stale frames.

Keyframes are shared too: one forced keyframe answers every viewer that asked for one
within ``KEYFRAME_MIN_INTERVAL_S`` (a keyframe is ~10× a frame, so one per viewer's
request would multiply everyone's bitrate), and a track asks only once it is sending
(its peer connected): a peer that never connects costs the stream nothing.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable

import av
from aiortc import MediaStreamTrack

from telerobot.server.media.encoder import EncodedFrame

log = logging.getLogger(__name__)

TRACK_QUEUE = 8  # frames a viewer may lag before it is resynchronised on a keyframe
# At most one forced keyframe per this many seconds, whoever asks and however often:
# a viewer waits at most this long (plus a frame) for its first picture or a resync,
# and 300 viewers asking at once cost the stream one keyframe, not 300.
KEYFRAME_MIN_INTERVAL_S = 0.5


class KeyframeGate:
    """Coalesces keyframe requests: ``ask`` marks that someone waits; the encoder is
    asked at most once per ``min_interval`` s, and any keyframe that goes out (asked
    for or the encoder's periodic one) answers everyone who asked before it."""

    def __init__(
        self,
        request_keyframe: Callable[[], None],
        min_interval: float = KEYFRAME_MIN_INTERVAL_S,
        now: Callable[[], float] = time.monotonic,
    ) -> None:
        self._request_keyframe = request_keyframe
        self.min_interval = min_interval
        self._now = now
        self._forced_at = -float("inf")
        self.waiting = False  # someone asked and no keyframe has gone out since
        self.forced = 0  # keyframes asked of the encoder (for tests and stats)

    def ask(self) -> None:
        self.waiting = True
        self.poll()

    def poll(self) -> None:
        """Ask the encoder if someone waits and the interval has passed (called per frame)."""
        if self.waiting and self._now() - self._forced_at >= self.min_interval:
            self._forced_at = self._now()
            self.forced += 1
            self._request_keyframe()

    def sent(self, frame: EncodedFrame) -> None:
        if frame.keyframe:
            self.waiting = False


class SharedVideoTrack(MediaStreamTrack):
    kind = "video"

    def __init__(self, source: Broadcaster) -> None:
        super().__init__()
        self._queue: deque[EncodedFrame] = deque()
        self._ready = asyncio.Event()
        self.source = source  # the layer whose frames this track sends
        # Moving to another layer (``move_to``): the old layer's frames keep going out
        # until the new one's first keyframe, so a switch never shows a gap.
        self.joining: Broadcaster | None = None
        # Not sending until aiortc first asks for a frame (its peer has connected):
        # until then frames pass it by and it asks for nothing.
        self.sending = False
        self._waiting_for_keyframe = True
        self.sent_frames = 0
        self.sent_bytes = 0
        self.resyncs = 0
        self.switches = 0  # layer changes done

    def _request_keyframe(self) -> None:
        (self.joining or self.source).keyframes.ask()

    def move_to(self, layer: Broadcaster) -> None:
        """Send ``layer``'s frames from its next keyframe on (asked for now); until then
        the current layer's. Moving back before that keyframe cancels the move."""
        if layer is self.source:
            if self.joining is not None:
                self.joining.tracks.discard(self)
                self.joining = None
            return
        if self.joining is not None and self.joining is not layer:
            self.joining.tracks.discard(self)
        self.joining = layer
        layer.tracks.add(self)
        if self.sending:
            layer.keyframes.ask()

    def push(self, frame: EncodedFrame, source: Broadcaster | None = None) -> None:
        """One frame from ``source`` (the track's own layer when None)."""
        if not self.sending:
            return
        if source is not None and source is self.joining:
            if not frame.keyframe:
                return  # the new layer counts from its keyframe
            self.source.tracks.discard(self)
            self.source, self.joining = source, None
            self._queue.clear()  # the old layer's frames would not decode after this one
            self._waiting_for_keyframe = False
            self.switches += 1
        elif source is not None and source is not self.source:
            return
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

    def start_sending(self) -> None:
        """The peer is connected: start on the next keyframe, and ask for one."""
        if not self.sending:
            self.sending = True
            self._waiting_for_keyframe = True
            self._request_keyframe()

    async def recv(self) -> av.Packet:  # type: ignore[type-arg]
        self.start_sending()  # aiortc asks for frames only once DTLS is up
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
        self.source.tracks.discard(self)
        if self.joining is not None:
            self.joining.tracks.discard(self)


class Broadcaster:
    """The set of live tracks; ``publish`` hands one encoded frame to all of them."""

    def __init__(
        self,
        request_keyframe: Callable[[], None],
        now: Callable[[], float] = time.monotonic,
        keyframe_min_interval: float = KEYFRAME_MIN_INTERVAL_S,
    ) -> None:
        self.keyframes = KeyframeGate(request_keyframe, keyframe_min_interval, now)
        self.tracks: set[SharedVideoTrack] = set()

    def new_track(self) -> SharedVideoTrack:
        # No keyframe yet: the track asks for one when its peer connects.
        track = SharedVideoTrack(self)
        self.tracks.add(track)
        return track

    def request_keyframe(self) -> None:
        self.keyframes.ask()

    @property
    def viewers(self) -> int:
        """Tracks sending this layer (one moving here counts where it still is)."""
        return sum(1 for t in self.tracks if t.source is self)

    @property
    def sending(self) -> int:
        """Tracks whose peer is connected and takes frames, or waits for this layer's
        keyframe to move here (only these need encoding)."""
        return sum(1 for t in self.tracks if t.sending)

    def publish(self, frame: EncodedFrame) -> None:
        self.keyframes.sent(frame)
        for track in list(self.tracks):
            track.push(frame, self)
        self.keyframes.poll()  # a request deferred by the interval goes out when due
