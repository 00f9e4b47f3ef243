"""Frames shown as soon as they are decoded: the playout-delay RTP header extension
(http://www.webrtc.org/experiments/rtp-hdrext/playout-delay) at 0–0 ms on every
video packet, as cloud gaming senders do.

Why: without it Chromium's jitter buffer holds each frame for its own estimate of the
stream's jitter, which grows with the spread of frame sizes (a still scene topped up
with filler, key frames). ``jitterBufferTarget = 0`` in the page only lowers the
*least* it may hold. ``bench.browser`` measured 21 ms of jitter-buffer delay per
frame on loopback, half of the page's capture → decoded p50 (42 ms). A 0–0 playout
delay tells the receiver to decode and show each frame when it is complete. An
operator wants the newest picture, not the smoothest.

aiortc negotiates only the extensions it lists (``HEADER_EXTENSIONS``) and writes only
those it knows; this adds the URI to its list (``allow``) and writes the element into
each RTP packet as it leaves (``ZeroPlayoutDelay`` in front of the transport's RTP
path, as the pacer is).
"""

from __future__ import annotations

import struct
from collections.abc import Awaitable, Callable
from typing import Any

from aiortc.rtp import is_rtcp

from telerobot.server.media.rtp_extensions import ONE_BYTE_PROFILE, block

URI = "http://www.webrtc.org/experiments/rtp-hdrext/playout-delay"
OFFER_ID = 5  # the id when we offer (aiortc's own video extensions take 1 and 3)
ZERO = b"\x00\x00\x00"  # 12 bits of minimum, 12 of maximum delay, in 10 ms units

Send = Callable[[bytes], Awaitable[None]]


def allow() -> None:
    """Let aiortc negotiate the extension for video (once per process)."""
    from aiortc.codecs import HEADER_EXTENSIONS
    from aiortc.rtcrtpparameters import RTCRtpHeaderExtensionParameters

    video = HEADER_EXTENSIONS["video"]
    if all(x.uri != URI for x in video):
        video.append(RTCRtpHeaderExtensionParameters(id=OFFER_ID, uri=URI))


def negotiated_id(pc: Any) -> int | None:
    """The id both peers agreed on for the extension on ``pc``'s video (None: not
    agreed), from aiortc's transceivers (it has no public accessor)."""
    for transceiver in pc.getTransceivers():
        if transceiver.kind != "video":
            continue
        for x in getattr(transceiver, "_headerExtensions", []):
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


class ZeroPlayoutDelay:
    """In front of a transport's RTP path: each RTP packet leaves with a 0–0 playout
    delay."""

    def __init__(self, send: Send, ext_id: int) -> None:
        self._send = send
        self.ext_id = ext_id

    async def __call__(self, data: bytes) -> None:
        # The transport's RTCP (sender reports) takes the same path: left as it is
        await self._send(data if is_rtcp(data) else with_element(data, self.ext_id, ZERO))


def zero_playout_delay(pc: Any) -> bool:
    """Put ``ZeroPlayoutDelay`` in front of the video sender's transport, if the peers
    agreed on the extension (else the receiver keeps its own jitter buffer). Before
    the pacer: it then paces the packets as they will leave."""
    ext_id = negotiated_id(pc)
    if ext_id is None:
        return False
    for transceiver in pc.getTransceivers():
        transport = getattr(transceiver.sender, "transport", None)
        send = getattr(transport, "_send_rtp", None)
        if transceiver.kind != "video" or send is None or isinstance(send, ZeroPlayoutDelay):
            continue
        assert transport is not None
        transport._send_rtp = ZeroPlayoutDelay(send, ext_id)  # the sender calls this
        return True
    return False
