"""The one goal waiting for the SO-101's bus, between the event loop and the poller
thread (arm.py). The bus is half duplex, one transaction at a time, and the poller
owns its timing: a goal taken on the loop waits here and the poller writes it before
its next read (``wake`` cuts its wait short). Newest wins: a goal still waiting when
a newer one comes is replaced. A brake empties the slot as it writes, so a goal
taken before a stop never goes out after it."""

from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np

from telerobot.drivers.motors.feetech.bus import FeetechPort

GOAL_DELAYS_KEPT = 10_000


class GoalSlot:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.out: tuple[bytes, float] | None = None  # packet, when taken
        self.wake = threading.Event()
        # Time from a goal taken to it on the bus (s), the newest few thousand.
        self.to_bus_s: deque[float] = deque(maxlen=GOAL_DELAYS_KEPT)

    def put(self, packet: bytes) -> None:
        """``packet`` taken now, for the poller's next turn (on the event loop)."""
        with self.lock:
            self.out = (packet, time.monotonic())
        self.wake.set()

    def write(self, bus: FeetechPort, faulted: threading.Event) -> None:
        """The waiting goal on the bus, unless the arm ``faulted`` (the poller's thread)."""
        # Under the lock, taken and written as one: a brake (which takes the lock too) is
        # never overtaken by a goal taken before it.
        with self.lock:
            out, self.out = self.out, None
            if out is None or faulted.is_set():
                return
            packet, taken = out
            bus.transact(packet, [])  # a failure stops the poller: the arm faults
        self.to_bus_s.append(time.monotonic() - taken)

    def brake(self, bus: FeetechPort, packet: bytes) -> None:
        """``packet`` (a stop) on the bus at once; any goal still waiting is dropped."""
        with self.lock:
            self.out = None
            bus.transact(packet, [])

    def waits_ms(self) -> dict[str, float]:
        """How long goals waited for the bus (ms): p50, p99, max and n; {} before any."""
        delays = np.array(self.to_bus_s) * 1000.0
        if len(delays) == 0:
            return {}
        return {
            "p50": float(np.percentile(delays, 50)),
            "p99": float(np.percentile(delays, 99)),
            "max": float(delays.max()),
            "n": len(delays),
        }
