"""What bench.wan's aiortc viewer adds to aiortc's receiver so that it receives as
libwebrtc's (Chromium's) does on a lossy link:

* **FEC**: RED unwrapped and lost packets rebuilt from ULPFEC (``FecReceiver`` of
  telerobot/server/media/fec.py) before aiortc sees the packets; an FEC packet reaches
  aiortc as an empty packet of the media (libwebrtc counts it as padding), so its
  number is not NACKed and the frame after it is released, as in libwebrtc's H.264
  packet buffer, only once every earlier number has come.
* **The playout delay** the server stamps on each packet (the playout-delay header
  extension, min = max): a decoded frame is shown at the time the stream's fastest
  frames would show it (its RTP time on the floor of the transit times seen) plus the
  current delay, or at once if it is later than that, as libwebrtc's VCMTiming renders
  it. As there, the current delay moves to the stamped one by at most
  ``DELAY_CHANGE_PER_S`` of stream time (the picture runs 10 % slow or fast meanwhile,
  where a jump would stop it for the whole step).

* **A gap skipped** (``keyframe_skipping_buffer``): a key frame received after a
  missing packet is decoded at once, and a gap the NACKs did not fill asks for one.

``install()`` before the peer connection is made (the offer then carries RED, ULPFEC
and the extension), or ``allow()`` and then ``attach()`` to one peer's transport;
``Playout.show_at`` per decoded frame; ``keyframe_skipping_buffer()`` in place of the
receiver's jitter buffer.
"""

from __future__ import annotations

import time
from typing import Any

from telerobot.server.media import fec, playout
from telerobot.server.media.rtp_extensions import block
from telerobot.server.telemetry.stats import DriftingFloor

# The transit floor rises this fast (s per s) when no frame is as fast: a link whose
# delay grew is followed within seconds (libwebrtc's timestamp extrapolator does the
# same with a filter).
FLOOR_DRIFT = 0.02
DELAY_CHANGE_PER_S = 0.1  # libwebrtc's kDelayMaxChangeMsPerS: 100 ms a second


class Received:
    """What the receiver saw: the FEC's counts and the newest playout delay (ms)."""

    def __init__(self) -> None:
        self.fec = fec.FecReceiver(fec.RED_OFFER_PT, fec.ULPFEC_OFFER_PT)
        self.delay_ms = 0
        self.delays_seen: set[int] = set()


def allow() -> None:
    """Offer RED, ULPFEC and the playout delay from now on (this process)."""
    fec.allow()
    playout.allow()


def _receiving(received: Received, original: Any) -> Any:
    async def handle(self: Any, data: bytes, arrival_time_ms: int) -> None:
        found = block(data)
        for x_id, at, length in found.elements if found is not None else []:
            if x_id == playout.OFFER_ID and length == 3:
                received.delay_ms = playout.read_element(data[at : at + 3])[0]
                received.delays_seen.add(received.delay_ms)
        for packet in received.fec.receive(data):
            await original(self, packet, arrival_time_ms)

    return handle


def install() -> Received:
    """``allow()``, and the FEC receiver in front of aiortc's RTP handling, of every
    DTLS transport in this process (bench.wan's viewer has one)."""
    from aiortc.rtcdtlstransport import RTCDtlsTransport

    allow()
    received = Received()
    handle = _receiving(received, RTCDtlsTransport._handle_rtp_data)
    RTCDtlsTransport._handle_rtp_data = handle  # type: ignore[method-assign]
    return received


def attach(transport: Any) -> Received:
    """The same on one DTLS transport (a test's viewer), after ``allow()``."""
    received = Received()
    original = type(transport)._handle_rtp_data
    handle = _receiving(received, original)

    async def bound(data: bytes, arrival_time_ms: int) -> None:
        await handle(transport, data, arrival_time_ms)

    transport._handle_rtp_data = bound
    return received


class Playout:
    """When to show each decoded frame: ``show_at(now, rtp_seconds, delay_s)``."""

    def __init__(self) -> None:
        self._floor = DriftingFloor(FLOOR_DRIFT)
        self.delay_s = 0.0  # the current delay
        self._rtp_s: float | None = None

    def show_at(self, now: float, rtp_s: float, delay_s: float) -> float:
        floor = self._floor.update(now - rtp_s, now)
        step = 0.0 if self._rtp_s is None else max(0.0, rtp_s - self._rtp_s) * DELAY_CHANGE_PER_S
        self._rtp_s = rtp_s
        self.delay_s += max(-step, min(step, delay_s - self.delay_s))
        return max(now, floor + rtp_s + self.delay_s)


# While it waits for a key frame, libwebrtc's receiver asks again this often (its
# max_wait_for_keyframe): the server sends key frames only when asked, so a lost
# request must not leave the picture frozen.
KEYFRAME_REASK_S = 0.2


def keyframe_skipping_buffer(
    give_up_s: float, reask_s: float = KEYFRAME_REASK_S, clock: Any = time.monotonic
) -> Any:
    """aiortc's video jitter buffer, which waits at a missing packet until 512 more have
    come (seconds), made to go on as libwebrtc does: a key frame received after a gap
    is decoded at once (libwebrtc's packet buffer holds back delta frames after a
    missing packet, never a key frame), and a gap the NACKs did not fill within
    ``give_up_s`` asks for a key frame, again every ``reask_s`` until one has come."""
    from aiortc.jitterbuffer import JitterBuffer

    def key_frame_start(packet: Any) -> bool:
        data = getattr(packet, "_data", b"")  # depayloaded: Annex B
        return len(data) > 4 and data[:4] == b"\x00\x00\x00\x01" and data[4] & 0x1F in (5, 7)

    class Skipping(JitterBuffer):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__(capacity=512, is_video=True)
            self.gap_since: float | None = None
            self.asked_at: float | None = None
            self.skips = 0

        def add(self, packet: Any) -> tuple[bool, Any]:
            pli, frame = super().add(packet)
            if frame is not None or self._origin is None:
                self.gap_since, self.asked_at = None, None
                return pli, frame
            newest = (packet.sequence_number - self._origin) % 65536
            slots = [
                self._packets[(self._origin + i) % self._capacity]
                for i in range(min(newest, self._capacity - 1) + 1)
            ]
            if all(p is not None for p in slots):
                return pli, frame  # a frame still arriving, no gap
            hole = slots.index(None)
            for count in range(hole + 1, len(slots)):
                p = slots[count]
                if p is not None and key_frame_start(p):
                    self.remove(count)
                    self.skips += 1
                    self.gap_since, self.asked_at = None, None
                    return pli, self._remove_frame(p.sequence_number)
            now = clock()
            if self.gap_since is None:
                self.gap_since = now
                return pli, frame
            if now - self.gap_since < give_up_s:
                return pli, frame
            ask = self.asked_at is None or now - self.asked_at >= reask_s
            if ask:
                self.asked_at = now
            return pli or ask, frame

    return Skipping()
