"""The one clock-sync rule (``telerobot.protocol.clock``) every client uses."""

from __future__ import annotations

import pytest

from telerobot.protocol.clock import ClockSync


def test_the_offset_of_the_shortest_round_trip_is_kept() -> None:
    clock = ClockSync()
    # The server's clock is 100 s ahead; the way out takes 1 ms, back 1 ms, it answers in 0.
    assert clock.pong(10.0, 110.001, 110.001, 10.002) == pytest.approx(0.002)
    assert clock.offset == pytest.approx(100.0)
    # A queued exchange (50 ms out, 1 ms back): a longer round trip, its skewed offset ignored.
    assert clock.pong(20.0, 120.05, 120.05, 20.051) == pytest.approx(0.051)
    assert clock.offset == pytest.approx(100.0) and clock.best_rtt == pytest.approx(0.002)
    # The server's time between receiving and answering is not part of the round trip.
    clock.pong(30.0, 130.0005, 130.5005, 30.501)
    assert clock.best_rtt == pytest.approx(0.001) and clock.offset == pytest.approx(100.0)
