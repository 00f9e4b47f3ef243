"""The priority channel's force path (priority.py), on the sensor's own thread: every
force sample the moment it is taken, as one FORCE, to every client that has said
HELLO: into its TCP queue (sent at once where the socket takes it), or as a UDP
datagram to an operator who registered for them (priority_datagrams.py).

The sensor's thread only ever takes one client's lock, held by others for a
non-blocking ``send`` at most, and only for clients that have said HELLO."""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from telerobot.drivers.base import ForceSample
from telerobot.protocol import messages as m
from telerobot.server.control.arm_guard import arm_sensors
from telerobot.server.realtime.priority_connection import Kind, PriorityClient
from telerobot.server.realtime.priority_datagrams import DATAGRAM_TIMEOUT_S, ForceDatagrams


class ForceFanout:
    def __init__(self, datagrams: ForceDatagrams, wake: Callable[[], None]) -> None:
        self.datagrams = datagrams
        self._wake = wake  # the channel's thread: it sends the rest when the socket drains
        # Those that said HELLO: the only ones the sensor's thread writes to.
        self.subscribers: tuple[PriorityClient, ...] = ()
        self._lock = threading.Lock()  # between writers; the sensor never takes it
        self._unsubscribe: list[Callable[[], None]] = []
        self.samples_sent = 0

    def subscribe(self, arms: Sequence[Any]) -> None:
        """Every arm's sensor, each FORCE naming its arm."""
        for index, sensor in arm_sensors(arms):
            # First: the other subscribers wake the event loop (call_soon_threadsafe),
            # whose thread then takes the GIL from this one, and under video a loop
            # thread put off the CPU while holding it made the datagram wait with it
            # (bench.force_under_video: p99 1.3 → 0.6 ms under video, 0.35 → 0.15 without).
            self._unsubscribe.append(
                sensor.subscribe(functools.partial(self.on_force, arm=index), first=True)
            )

    def unsubscribe(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()

    def add(self, client: PriorityClient) -> None:
        with self._lock:  # from now on the sensor's thread sends it forces
            self.subscribers = (*self.subscribers, client)

    def drop(self, client: PriorityClient) -> None:
        with self._lock:
            if client in self.subscribers:
                self.subscribers = tuple(c for c in self.subscribers if c is not client)

    def on_force(self, sample: ForceSample, arm: int = 1) -> None:
        message = m.encode_force([(sample.seq, sample.time, sample.values)], arm)
        data = m.frame(message)
        look = False
        now = time.monotonic()
        for client in self.subscribers:  # only clients that said HELLO
            if client.closed:
                continue
            self.samples_sent += 1
            addr = client.datagram_addr
            if addr is not None and now - client.datagram_heard < DATAGRAM_TIMEOUT_S:
                if sample.seq % client.datagram_every == 0:
                    self.datagrams.offer(client, message, addr, now)
            else:
                look |= client.push(data, Kind.FORCE)
        if look:
            self._wake()  # the channel's thread sends the rest when the socket drains
