"""State and forces for observers who watch through the media server, at a
reduced rate, without a connection to the control server per observer.

Janus relays UDP datagrams that reach its mountpoint's data port to every viewer's data
channel (a viewer opens "JanusDataChannel" before answering; Janus drops whatever a
viewer sends on it: the streaming plugin has no handler for incoming data). So this
sends, ``rate_hz`` times a second, one STATE (as an observer sees it: never "you have
control") and one FORCE batch of every ``force_every``-th sample since the last, in
the realtime protocol's own binary messages (docs/protocol.md), each one datagram
(Janus cuts them at 1500 bytes: a batch is at most ``MAX_BATCH`` samples, 63 bytes
each). A thousand observers cost the robot's computer what one does: two datagrams a
tick. Nothing comes back this way, so the control lease is not reachable through it.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import socket
from collections import deque

from telerobot.drivers.base import ForceSample
from telerobot.protocol import messages as m
from telerobot.server.control.arm_guard import arm_sensors
from telerobot.server.realtime.hub import RealtimeHub

log = logging.getLogger(__name__)

RATE_HZ = 20.0  # STATE and a FORCE batch, this often
FORCE_EVERY = 10  # of the sensor's samples: 1 kHz → 100 Hz
MAX_BATCH = 20  # samples in one datagram (3 + 20 × 60 = 1203 bytes < 1500)


class ObserverFeed:
    def __init__(
        self,
        hub: RealtimeHub,
        host: str,
        port: int,
        *,
        rate_hz: float = RATE_HZ,
        force_every: int = FORCE_EVERY,
    ) -> None:
        self.hub = hub
        self.to = (host, port)
        self.period = 1.0 / rate_hz
        self.force_every = force_every
        # Filled by the sensor's thread (deque appends are atomic), emptied each tick;
        # bounded: a stalled loop keeps the newest.
        # Per arm (its index on the wire): every arm's STATE and FORCE go out, each
        # naming its arm.
        self._samples: dict[int, deque[ForceSample]] = {
            g.index: deque(maxlen=MAX_BATCH) for g in hub.decision.arms
        }
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._task: asyncio.Task[None] | None = None
        self._unsubscribe: list[object] = []
        self.sent = 0
        self.failed = 0

    def _on_force(self, sample: ForceSample, arm: int = 1) -> None:
        if sample.seq % self.force_every == 0:
            self._samples[arm].append(sample)

    def start(self) -> None:
        for index, sensor in arm_sensors(self.hub.decision.arms):
            self._unsubscribe.append(sensor.subscribe(functools.partial(self._on_force, arm=index)))
        self._task = asyncio.create_task(self._run(), name="observer-feed")

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()  # type: ignore[operator]
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        self._sock.close()

    def tick(self) -> None:
        """Each arm's STATE and FORCE samples since the last tick (if any), a datagram
        each."""
        out = self.hub.encode_states_for(None, False)
        for arm, samples in self._samples.items():
            batch = []
            while True:  # popleft: a sample the sensor's thread adds meanwhile stays
                try:
                    s = samples.popleft()
                except IndexError:
                    break
                batch.append((s.seq, s.time, s.values))
            if batch:
                out.append(m.encode_force(batch, arm))
        for data in out:
            try:
                self._sock.sendto(data, self.to)
                self.sent += 1
            except OSError:  # the media server restarting: its port is closed a moment
                self.failed += 1

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(self.period)
            self.tick()
