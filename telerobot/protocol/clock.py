"""The client's estimate of the server's clock, from PING/PONG (docs/protocol.md): the
one rule every client uses (the master bridge's link, the benches' client; the page's
is its TypeScript twin in web/src/transport/clocksync.ts).

Each PONG carries the server's receive and send times (t1, t2); with the client's send
and receive times (t0, t3) the round trip is (t3 − t0) − (t2 − t1) and the offset
(server − client) ((t1 − t0) + (t2 − t3)) / 2, NTP's. The exchange with the shortest
round trip is the least disturbed by queueing, so it is the one kept.
"""

from __future__ import annotations

import math


class ClockSync:
    """The offset (server clock − this clock, s) of the shortest round trip seen."""

    def __init__(self) -> None:
        self.offset = 0.0
        self.best_rtt = math.inf

    def pong(self, t0: float, t1: float, t2: float, t3: float) -> float:
        """One exchange: sent at ``t0``, received by the server at ``t1``, answered at
        ``t2``, back at ``t3`` (each on its own clock). Returns its round trip."""
        rtt = (t3 - t0) - (t2 - t1)
        if rtt < self.best_rtt:
            self.best_rtt = rtt
            self.offset = ((t1 - t0) + (t2 - t3)) / 2
        return rtt
