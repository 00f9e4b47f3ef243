"""A pacer for each viewer's video packets (as libwebrtc's): a frame's packets go out
spread at ``PACING_FACTOR`` × the layer's measured rate instead of in one burst.
Off unless ``video_pacing`` (settings.py says why).

Why: aiortc writes all of a frame's packets at once. A key frame is tens of kB, which
a 4 Mbit/s link takes ~100 ms to carry. Everything sent behind it on the same link
waits in the link's queue: the forces (UDP datagrams, 1 kHz) and the commands' ACKs.
DSCP EF would put them first only where a router honours it, and a typical bottleneck
(a home router, a mobile cell, netem/HTB in bench.netem) is one FIFO. Paced below the
link's rate, the video never builds that queue: the link drains faster than the pacer
fills it, so a force sample waits behind at most a packet or two. The burst waits in
this process instead, in a queue that drains within ``MAX_QUEUE_S``. Only RTP is
paced; RTCP goes at once.

abs-send-time (the header extension Chromium's receive-side bandwidth estimate reads)
is stamped by aiortc when it builds the packet, before this waits; it is written again
here at the moment the packet really leaves, as libwebrtc's pacer does. Otherwise the
pacer's own delay would read as a growing queue on the link, and the estimate (and the
layer choice that follows it) would fall for nothing.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections import deque
from collections.abc import Awaitable, Callable
from typing import Any

from aiortc.clock import current_ntp_time
from aiortc.rtp import is_rtcp

from telerobot.server.media import aiortc_compat
from telerobot.server.media.rtp_extensions import block

PACING_FACTOR = 2.5  # × the layer's measured rate (libwebrtc's default)
MIN_RATE_BPS = 1_000_000  # never slower than this (a still scene's stream is tiny)
BURST_S = 0.005  # what may go at once: 5 ms worth at the pacing rate…
MIN_BURST_BYTES = 2 * 1300  # …but at least two full packets
# The queue drains within this: with more waiting, the rate rises to match (libwebrtc
# bounds its pacer's queue the same way). A key frame thus leaves within ~0.1-0.2 s,
# and the sender's loop never waits: it hands over and goes on, so no frame of the
# shared encoder is skipped (a skipped P-frame would break the picture until the next
# key frame).
MAX_QUEUE_S = 0.1
MAX_QUEUE_PACKETS = 4096  # a transport that stopped taking them: beyond, at once

Send = Callable[[bytes], Awaitable[None]]


class Pacer:
    """A queue and a token bucket in front of one transport's RTP. ``rate_bps`` says
    the layer's measured rate now (None: not known yet, nothing is paced);
    ``abs_send_time_id`` is the negotiated id of that header extension (None: not
    negotiated). Packets are handed over at once and sent, in order, by a task of the
    pacer's own; ``close()`` ends it."""

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
        self._queue: deque[bytes] = deque()
        self._queued_bytes = 0
        self._ready = asyncio.Event()  # something is queued
        self._idle = asyncio.Event()  # nothing is (for close and tests)
        self._idle.set()
        self._task: asyncio.Task[None] | None = None
        self._tokens = 0.0  # bytes that may go now
        self._last = clock()
        self.paced = 0  # packets that had to wait
        self.waited_s = 0.0  # in all
        self.lost_transport = 0  # packets dropped because the transport had closed

    def rate(self) -> float | None:
        """The pacing rate (bit/s) now, or None (not pacing)."""
        measured = self._rate_bps()
        if measured is None:
            return None
        return max(PACING_FACTOR * measured, MIN_RATE_BPS)

    @property
    def queued(self) -> int:
        return len(self._queue)

    async def __call__(self, data: bytes) -> None:
        if is_rtcp(data) or (not self._queue and self.rate() is None):
            await self._send(self.stamp(data))  # reports and feedback, or not pacing
            return
        if len(self._queue) >= MAX_QUEUE_PACKETS:  # (never on a live transport)
            await self._send(self.stamp(data))  # out of order, rather than lost
            return
        self._queue.append(data)
        self._queued_bytes += len(data)
        self._idle.clear()
        self._ready.set()
        if self._task is None:
            self._task = asyncio.ensure_future(self._drain())

    async def drained(self) -> None:
        await self._idle.wait()

    def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        self._queue.clear()
        self._queued_bytes = 0
        self._idle.set()

    async def _drain(self) -> None:
        while True:
            if not self._queue:
                self._idle.set()
                self._ready.clear()
                await self._ready.wait()
                continue
            data = self._queue[0]
            bytes_per_s = max((self.rate() or math.inf) / 8, self._queued_bytes / MAX_QUEUE_S)
            await self._wait(len(data), bytes_per_s)
            self._queue.popleft()
            self._queued_bytes -= len(data)
            try:
                await self._send(self.stamp(data))
            except ConnectionError:  # the transport has closed: nothing more will go
                self.lost_transport += 1 + len(self._queue)
                self._queue.clear()
                self._queued_bytes = 0

    async def _wait(self, size: int, bytes_per_s: float) -> None:
        if math.isinf(bytes_per_s):
            return
        self._refill(bytes_per_s)
        if self._tokens < size:
            delay = (size - self._tokens) / bytes_per_s
            self.paced += 1
            self.waited_s += delay
            await self._sleep(delay)
            self._refill(bytes_per_s)
        self._tokens -= size

    def _refill(self, bytes_per_s: float) -> None:
        """The bucket after the time since the last refill, at most one burst full."""
        burst = max(bytes_per_s * BURST_S, MIN_BURST_BYTES)
        now = self._clock()
        self._tokens = min(burst, self._tokens + (now - self._last) * bytes_per_s)
        self._last = now

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
    found = block(packet)
    for x_id, at, length in found.elements if found is not None else []:
        if x_id == ext_id:
            return at if length == 3 else None
    return None


def negotiated_id(sender: Any) -> int | None:
    """The abs-send-time id the peers agreed on for this aiortc sender (None if none),
    from its private header-extension map (aiortc has no accessor for it)."""
    return aiortc_compat.extension_id(sender, "abs_send_time")


def pace_peer(pc: Any, rate_bps: Callable[[], float | None]) -> Pacer | None:
    """Put a pacer in front of the video sender's transport (its RTP path); None if
    aiortc's internals are not where they were."""
    senders = [t.sender for t in pc.getTransceivers() if getattr(t, "sender", None)]
    for sender in senders:
        transport = getattr(sender, "transport", None)
        send = aiortc_compat.send_rtp_path(transport)
        if transport is None or send is None or isinstance(send, Pacer):
            continue
        pacer = Pacer(send, rate_bps, negotiated_id(sender))
        aiortc_compat.put_in_rtp_path(transport, pacer)
        return pacer
    return None
