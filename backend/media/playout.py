"""The playout-delay RTP header extension
(http://www.webrtc.org/experiments/rtp-hdrext/playout-delay) on every video packet:
frames shown as soon as they are decoded (0–0 ms, as cloud gaming senders do) on a
clean link, and held by a delay that covers a repair where the link loses packets
(``AdaptivePlayout``).

Why: without it Chromium's jitter buffer holds each frame for its own estimate of the
stream's jitter, which grows with the spread of frame sizes (a still scene topped up
with filler, key frames). ``jitterBufferTarget = 0`` in the page only lowers the
*least* it may hold. ``bench.browser`` measured 21 ms of jitter-buffer delay per
frame on loopback, half of the page's capture → decoded p50 (42 ms). A 0–0 playout
delay tells the receiver to decode and show each frame when it is complete. An
operator wants the newest picture, not the smoothest.

Why it grows on a lossy link: a frame that lost a packet waits for its repair, a NACK
round trip (170–280 ms on bench.netem's `mobile` link), and every frame behind it
waits too. Shown at once, the picture stops for that long and then jumps. Held by the
time a repair takes (``AdaptivePlayout``: the round trip and the jitter, less the two
frame intervals a late frame may be without a visible stop), a repaired frame is
shown on time and the picture flows, later by that delay. The delay grows at once
when the viewer asks for a repair, holds while repairs go on, and shrinks back to 0
``HOLD_S`` after the last one. Min and max are both the delay: libwebrtc then holds
each frame that long after the time it expected it, and ignores its own jitter
estimate (which grew with the spread of frame sizes, not with the repairs).

aiortc negotiates only the extensions it lists (``HEADER_EXTENSIONS``) and writes only
those it knows; this adds the URI to its list (``allow``) and writes the element into
each RTP packet as it leaves (``PlayoutDelayStamp`` in front of the transport's RTP
path, as the pacer is).
"""

from __future__ import annotations

import math
import struct
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any

from aiortc.rtp import is_rtcp

from telerobot.server.media import aiortc_compat
from telerobot.server.media.rtp_extensions import ONE_BYTE_PROFILE, block

URI = "http://www.webrtc.org/experiments/rtp-hdrext/playout-delay"
OFFER_ID = 5  # the id when we offer (aiortc's own video extensions take 1 and 3)
ZERO = b"\x00\x00\x00"  # 12 bits of minimum, 12 of maximum delay, in 10 ms units
UNIT_MS = 10
# Never held longer (the operator's picture would lag too far); an operator may set
# less (video_playout_max_ms).
MAX_DELAY_MS = 500
HOLD_S = 10.0  # a repair's need holds this long…
MAX_REPAIRS_KEPT = 256  # (repairs remembered for that: a burst of NACKs is many)
SHRINK_MS_PER_S = 50.0  # …then shrinks back this fast
# A repaired frame this late (two frame intervals at 30 fps, four at 60: a time the eye
# sees, not a count of frames) still shows before the picture visibly stops: the delay
# covers only the rest of a repair.
TOLERANCE_S = 0.067
# A repair this much later than the cap is still waited for, the cap's worth: the stop
# left is shorter than WebRTC's freeze (the mean frame interval + 150 ms).
SHORT_STOP_MS = 100.0

Send = Callable[[bytes], Awaitable[None]]


def allow() -> None:
    """Let aiortc negotiate the extension for video (once per process)."""
    aiortc_compat.offer_video_extension(URI, OFFER_ID)


def negotiated_id(pc: Any) -> int | None:
    """The id both peers agreed on for the extension on ``pc``'s video (None: not
    agreed), from aiortc's transceivers (it has no public accessor)."""
    for transceiver in pc.getTransceivers():
        if transceiver.kind != "video":
            continue
        for x in aiortc_compat.agreed_extensions(transceiver):
            if x.uri == URI:
                return int(x.id)
    return None


def with_element(packet: bytes, ext_id: int, value: bytes) -> bytes:
    """``packet`` (RTP) with a one-byte header extension element ``ext_id`` = ``value``
    (RFC 8285), replacing one of that id; unchanged if it uses two-byte headers or
    is not RTP as expected."""
    found = block(packet)
    if found is None or not 1 <= ext_id <= 14 or not 1 <= len(value) <= 16:
        return packet
    elements = [(i, packet[at : at + n]) for i, at, n in found.elements if i != ext_id]
    elements.append((ext_id, value))
    body = b"".join(bytes([(i << 4) | (len(v) - 1)]) + v for i, v in elements)
    body += b"\x00" * (-len(body) % 4)
    header = bytes([packet[0] | 0x10]) + packet[1 : found.start]
    return (
        header + struct.pack("!HH", ONE_BYTE_PROFILE, len(body) // 4) + body + packet[found.end :]
    )


def element(min_ms: float, max_ms: float) -> bytes:
    """The extension's 3 bytes for a delay of ``min_ms``–``max_ms`` (10 ms units)."""
    lo = min(0xFFF, max(0, math.ceil(min_ms / UNIT_MS)))
    hi = min(0xFFF, max(lo, math.ceil(max_ms / UNIT_MS)))
    return ((lo << 12) | hi).to_bytes(3, "big")


def read_element(value: bytes) -> tuple[int, int]:
    """(min, max) in ms from the extension's 3 bytes."""
    n = int.from_bytes(value[:3], "big")
    return (n >> 12) * UNIT_MS, (n & 0xFFF) * UNIT_MS


class AdaptivePlayout:
    """The playout delay for one viewer (ms, a multiple of 10): 0 on a clean link; the
    most that the repairs asked for in the last ``HOLD_S`` need (what each takes, less
    ``TOLERANCE_S``), at once; shrinking by ``SHRINK_MS_PER_S`` towards that when it is
    less (the picture then catches up, a little faster than real time). ``now`` is
    any monotonic clock (s).

    The rule: a repair is waited for only while waiting saves the freeze, i.e. while it
    comes within ``max_ms``, or so little after it (``SHORT_STOP_MS``) that waiting the
    cap leaves a stop no viewer sees as one (WebRTC counts a freeze from the mean frame
    interval + 150 ms): on `bad` repairs took 0.45–0.55 s against the 0.5 s cap, and
    waiting for none turned each into a freeze of all of it. A repair that takes longer
    freezes the picture whatever the delay, so holding every frame for it would add the
    lag and keep the freeze (on bench.wan's `bad` link the delay sat at its 0.5 s cap
    with a queue behind it and the picture still froze): such a repair asks for no delay
    (``too_slow``)."""

    def __init__(self, max_ms: float = MAX_DELAY_MS) -> None:
        self.max_ms = max_ms
        self.delay_ms = 0.0
        self.repairs = 0
        self.too_slow = 0  # repairs not waited for: longer than max_ms
        self._needs: deque[tuple[float, float]] = deque(maxlen=MAX_REPAIRS_KEPT)
        self._target = 0.0  # the most of ``_needs`` (kept: asked for at every packet)
        self._at: float | None = None

    def repair(self, now: float, repair_s: float) -> None:
        """The viewer asked for a repair that takes ``repair_s`` (its round trip and
        jitter)."""
        self.repairs += 1
        need = max(0.0, (repair_s - TOLERANCE_S) * 1000)
        if need > self.max_ms + SHORT_STOP_MS:
            self.too_slow += 1
            return
        need = min(need, self.max_ms)
        self._needs.append((now, need))
        self._target = max(self._target, need)
        self.delay_ms = max(self.delay_ms, need)

    def current(self, now: float) -> int:
        """The delay now (call it now and then: the shrinking is by the time since)."""
        if self._needs and now - self._needs[0][0] > HOLD_S:
            while self._needs and now - self._needs[0][0] > HOLD_S:
                self._needs.popleft()
            self._target = max((need for _, need in self._needs), default=0.0)
        target = self._target
        since = 0.0 if self._at is None else max(0.0, now - self._at)
        self._at = now
        if target >= self.delay_ms:
            self.delay_ms = target
        else:
            self.delay_ms = max(target, self.delay_ms - SHRINK_MS_PER_S * since)
        return int(math.ceil(self.delay_ms / UNIT_MS) * UNIT_MS)


class PlayoutDelayStamp:
    """In front of a transport's RTP path: each RTP packet leaves with a playout delay
    of ``delay_ms()`` (min and max alike; 0 unless told)."""

    def __init__(self, send: Send, ext_id: int, delay_ms: Callable[[], int] | None = None) -> None:
        self._send = send
        self.ext_id = ext_id
        self._delay_ms = delay_ms
        self._value = (0, ZERO)

    def value(self) -> bytes:
        delay = 0 if self._delay_ms is None else self._delay_ms()
        if delay != self._value[0]:
            self._value = (delay, element(delay, delay))
        return self._value[1]

    async def __call__(self, data: bytes) -> None:
        # The transport's RTCP (sender reports) takes the same path: left as it is
        await self._send(data if is_rtcp(data) else with_element(data, self.ext_id, self.value()))


def stamp_playout_delay(pc: Any, delay_ms: Callable[[], int] | None = None) -> bool:
    """Put ``PlayoutDelayStamp`` in front of the video sender's transport, if the peers
    agreed on the extension (else the receiver keeps its own jitter buffer). Before
    the pacer and the FEC: the FEC then covers the packets as they will leave."""
    ext_id = negotiated_id(pc)
    if ext_id is None:
        return False
    for transceiver in pc.getTransceivers():
        transport = getattr(transceiver.sender, "transport", None)
        send = aiortc_compat.send_rtp_path(transport)
        if transceiver.kind != "video" or send is None or isinstance(send, PlayoutDelayStamp):
            continue
        aiortc_compat.put_in_rtp_path(transport, PlayoutDelayStamp(send, ext_id, delay_ms))
        return True
    return False
