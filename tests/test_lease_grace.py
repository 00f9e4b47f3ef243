"""The dead-man over the lease (backend/control/lease.py) over generated sequences: a
holder heard at any rhythm, with any stalls, then silent: its arm is stopped once the
dead-man's limit passes, and it loses the lease after the grace, lengthened by its own
recent stalls or its link's transit but never by more than MAX_GRACE_EXTENSION_S; it
never loses it within the plain grace."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from telerobot.server.control.clients import STALLS_KEPT, ClientTable
from telerobot.server.control.lease import MAX_GRACE_EXTENSION_S, Lease
from telerobot.server.control.limits import SafetyLimits

TOKEN = "operator-token-for-the-lease-test"
TICK_S = 0.01


class SteppedClock:
    """Virtual time moved by hand, one tick at a time (no event loop needed)."""

    t = 0.0

    def now(self) -> float:
        return self.t


@settings(max_examples=150, deadline=None)
@given(
    gaps=st.lists(st.floats(0.0, 5.0), max_size=40),
    transit=st.one_of(st.none(), st.floats(0.0, 2.0)),
)
def test_a_silent_holder_is_stopped_then_loses_the_lease_within_a_bounded_grace(
    gaps: list[float], transit: float | None
) -> None:
    clock = SteppedClock()
    limits = SafetyLimits()
    clients = ClientTable(clock, TOKEN)
    holder = clients.add("alice", TOKEN, synced_clock=transit is not None)
    holder.transit_avg = transit
    lease = Lease(clients, clock, limits)
    lease.give(holder, "taken")

    def tick_for(seconds: float) -> bool:
        """Ticks at TICK_S; True if the lease lapsed meanwhile."""
        end = clock.now() + seconds
        while clock.now() < end:
            clock.t += TICK_S
            verdict = lease.judge()
            if verdict is not None and verdict.lapse:
                lease.drop(verdict.why)
                return True
        return False

    for gap in gaps:  # heard after each gap (a stall past the grace loses it: then done)
        if tick_for(gap):
            return
        lease.heard(holder)
    last = clock.now()
    plain = limits.deadman_timeout_s + limits.lease_grace_s
    tick_for(limits.deadman_timeout_s + 2 * TICK_S)
    assert lease.holder == holder.id and lease.halted  # stopped, the lease kept
    lapsed = tick_for(plain + MAX_GRACE_EXTENSION_S + 1.0)
    assert lapsed and lease.holder is None
    silent = clock.now() - last
    assert plain <= silent <= plain + MAX_GRACE_EXTENSION_S + 3 * TICK_S, silent


def test_a_holders_remembered_stalls_are_bounded() -> None:
    clock = SteppedClock()
    limits = SafetyLimits()
    clients = ClientTable(clock, TOKEN)
    holder = clients.add("alice", TOKEN)
    lease = Lease(clients, clock, limits)
    lease.give(holder, "taken")
    for _ in range(3 * STALLS_KEPT):  # a stall each time it is heard
        clock.t += limits.deadman_timeout_s + 0.1
        lease.heard(holder)
    assert len(holder.stalls) == STALLS_KEPT
