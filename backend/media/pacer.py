"""A pacer for each viewer's video packets (as libwebrtc's): a frame's packets go out
spread at ``PACING_FACTOR`` × the layer's measured rate instead of in one burst.

Why: aiortc writes all of a frame's packets at once. A key frame is tens of kB, which
a 4 Mbit/s link takes ~100 ms to carry. Everything sent behind it on the same link
waits in the link's queue: the forces (UDP datagrams, 1 kHz) and the commands' ACKs.
DSCP EF would put them first only where a router honours it, and a typical bottleneck
(a home router, a mobile cell, netem/HTB in bench.netem) is one FIFO. Paced below the
link's rate, the video never builds that queue: the link drains faster than the pacer
fills it, so a force sample waits behind at most a packet or two. The burst waits in
this process instead (a key frame takes ~2.5× longer to leave than the encoder took to
make it). Only RTP is paced; RTCP goes at once.

abs-send-time (the header extension Chromium's receive-side bandwidth estimate reads)
is stamped by aiortc when it builds the packet, before this waits; it is written again
here at the moment the packet really leaves, as libwebrtc's pacer does. Otherwise the
pacer's own delay would read as a growing queue on the link, and the estimate (and the
layer choice that follows it) would fall for nothing.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Awaitable, Callable
from typing import Any

from aiortc.clock import current_ntp_time
from aiortc.rtp import is_rtcp

PACING_FACTOR = 2.5  # × the layer's measured rate (libwebrtc's default)
MIN_RATE_BPS = 1_000_000  # never slower than this (a still scene's stream is tiny)
BURST_S = 0.005  # what may go at once: 5 ms worth at the pacing rate…
MIN_BURST_BYTES = 2 * 1300  # …but at least two full packets

Send = Callable[[bytes], Awaitable[None]]


class Pacer:
    """A token bucket in front of one transport's RTP. ``rate_bps`` says the layer's
    measured rate now (None: not known yet, nothing is paced); ``abs_send_time_id`` is
    the negotiated id of that header extension (None: not negotiated)."""

    def __init__(
        self,
        send: Send,
        rate_bps: Callable[[], float | None],
        abs_send_time_id: int | None = None,
        *,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], Awaitable[Any]] = asyncio.sleep,
        ntp: Callable[[], int] = current_ntp_time,
    ) -> None:
        self._send = send
        self._rate_bps = rate_bps
        self.abs_send_time_id = abs_send_time_id
        self._clock = clock
        self._sleep = sleep
        self._ntp = ntp
        self._lock = asyncio.Lock()  # the sender's loop and NACK resends, in one line
        self._tokens = 0.0  # bytes that may go now
        self._last = clock()
        self.paced = 0  # packets that had to wait
        self.waited_s = 0.0  # in all

    def rate(self) -> float | None:
        """The pacing rate (bit/s) now, or None (not pacing)."""
        measured = self._rate_bps()
        if measured is None:
            return None
        return max(PACING_FACTOR * measured, MIN_RATE_BPS)

    async def __call__(self, data: bytes) -> None:
        if is_rtcp(data):
            await self._send(data)  # reports and feedback: at once
            return
        async with self._lock:
            rate = self.rate()
            if rate is not None:
                await self._wait(len(data), rate / 8)
            await self._send(self.stamp(data))

    async def _wait(self, size: int, bytes_per_s: float) -> None:
        burst = max(bytes_per_s * BURST_S, MIN_BURST_BYTES)
        now = self._clock()
        self._tokens = min(burst, self._tokens + (now - self._last) * bytes_per_s)
        self._last = now
        if self._tokens < size:
            delay = (size - self._tokens) / bytes_per_s
            self.paced += 1
            self.waited_s += delay
            await self._sleep(delay)
            now = self._clock()
            self._tokens = min(burst, self._tokens + (now - self._last) * bytes_per_s)
            self._last = now
        self._tokens -= size

    def stamp(self, data: bytes) -> bytes:
        """``data`` with its abs-send-time set to now, if it carries one."""
        if self.abs_send_time_id is None:
            return data
        at = abs_send_time_offset(data, self.abs_send_time_id)
        if at is None:
            return data
        value = (self._ntp() >> 14) & 0xFFFFFF
        return data[:at] + value.to_bytes(3, "big") + data[at + 3 :]


def abs_send_time_offset(packet: bytes, ext_id: int) -> int | None:
    """Where the 3 bytes of abs-send-time start in an RTP packet (one-byte header
    extensions, RFC 8285), or None if it has none."""
    if len(packet) < 12 or not packet[0] & 0x10:  # no extension
        return None
    at = 12 + 4 * (packet[0] & 0x0F)  # past the CSRCs
    if len(packet) < at + 4:
        return None
    profile, words = struct.unpack_from("!HH", packet, at)
    if profile != 0xBEDE:  # two-byte headers: aiortc does not write them
        return None
    pos, end = at + 4, min(len(packet), at + 4 + 4 * words)
    while pos < end:
        head = packet[pos]
        if head == 0:  # padding
            pos += 1
            continue
        x_id, length = head >> 4, (head & 0x0F) + 1
        if x_id == 15:
            return None
        if x_id == ext_id:
            return pos + 1 if length == 3 and pos + 4 <= end else None
        pos += 1 + length
    return None


def negotiated_id(sender: Any) -> int | None:
    """The abs-send-time id the peers agreed on for this aiortc sender (None if none),
    from its private header-extension map (aiortc has no accessor for it)."""
    extensions = getattr(sender, "_RTCRtpSender__rtp_header_extensions_map", None)
    ids = getattr(extensions, "_HeaderExtensionsMap__ids", None)
    value = getattr(ids, "abs_send_time", None)
    return int(value) if value else None


def pace_peer(pc: Any, rate_bps: Callable[[], float | None]) -> Pacer | None:
    """Put a pacer in front of the video sender's transport (its RTP path); None if
    aiortc's internals are not where they were."""
    senders = [t.sender for t in pc.getTransceivers() if getattr(t, "sender", None)]
    for sender in senders:
        transport = getattr(sender, "transport", None)
        send = getattr(transport, "_send_rtp", None)
        if transport is None or send is None or isinstance(send, Pacer):
            continue
        pacer = Pacer(send, rate_bps, negotiated_id(sender))
        transport._send_rtp = pacer  # the instance's attribute: the sender calls this
        return pacer
    return None
