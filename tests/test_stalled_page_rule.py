"""The server's side of a stalled page keeping its lease (issue 55), over generated
sequences (Hypothesis' stateful testing).

A page whose main thread stands still sends nothing; its realtime worker stops the
heartbeats, the server's dead-man stops the arm, and once the server has said so (a
STATE with HALTED) the worker, with the dead-man held, beats again to keep the lease
until the page is back (web/src/transport/heartbeat.ts; its rule over generated
sequences is web/src/page-silence.test.ts). What makes that safe is the server's: a
silent holder's arm is stopped within the dead-man's limit; any message keeps the lease;
a heartbeat never moves the arm; and a command sent before the stall that arrives after
it (older than the command age limit) is refused. Here the real DecisionServer on the
simulated PUMA in virtual time, driven as such a page drives it: fresh commands, the
worker's heartbeats, silences of any length, and late commands from before a silence.
"""

from __future__ import annotations

import contextlib

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import invariant, rule

from telerobot.drivers.base import TelerobotError
from telerobot.drivers.clock import ManualClock
from telerobot.server.control.decision import DecisionServer
from tests.support import TOKEN
from tests.support.decision import OwnLoopMachine, RecordingPuma, make

STEP_M = np.array([0.001, 0.0, 0.0])
# Silences around the dead-man's limit (0.15 s), a page's stall (1 s and more), the grace
# (2 s) and its longest extension (4 s), and any other.
SILENCES = st.one_of(
    st.sampled_from([0.02, 0.1, 0.16, 0.3, 0.6, 1.0, 1.3, 1.9, 2.2, 3.0, 4.5]),
    st.floats(0.0, 5.0),
)


class StalledPage(OwnLoopMachine):
    def __init__(self) -> None:
        super().__init__()
        self.clock = ManualClock()
        self.ds: DecisionServer
        self.robot: RecordingPuma
        self.ds, self.robot = self.run(make(self.clock))
        self.page = self.ds.join("page", TOKEN, synced_clock=True)
        self.run(self.ds.take_lease(self.page.id))
        limits = self.ds.limits
        self.limit, self.grace, self.tick_s = (
            limits.deadman_timeout_s,
            limits.lease_grace_s,
            limits.tick_s,
        )
        self.heard = self.clock.now()  # the server last heard the page then
        self.longest_silence = 0.0

    @property
    def holds(self) -> bool:
        return self.ds.lease_holder == self.page.id

    def arrives(self) -> None:
        """A message of the page's reaches the server (Session.receive: ``seen`` first)."""
        self.longest_silence = max(self.longest_silence, self.clock.now() - self.heard)
        self.heard = self.clock.now()
        self.ds.seen(self.page.id)

    def command(self, sent: float) -> bool:
        """An increment sent at ``sent`` (the server's clock) arrives now: whether it moved
        the arm."""
        self.arrives()
        before = len(self.robot.sent)
        with contextlib.suppress(TelerobotError):  # refused: it did not move the arm
            self.run(
                self.ds.cartesian_increment(self.page.id, STEP_M, np.zeros(3), client_time=sent)
            )
        return len(self.robot.sent) > before

    @rule()
    def drive(self) -> None:
        """A fresh increment (the page running, the dead-man and a key held)."""
        self.command(self.clock.now())

    @rule()
    def heartbeat(self) -> None:
        """The worker's heartbeat (the page running, or stalled once the arm stopped):
        it keeps the lease, and never moves the arm."""
        before = len(self.robot.sent)
        self.arrives()
        self.ds.heard_beat(self.page.id, self.clock.now())
        assert len(self.robot.sent) == before

    @rule(seconds=SILENCES)
    def silence(self, seconds: float) -> None:
        """Nothing from the page for this long (a stalled main thread, its worker not
        beating yet), the dead-man checked every tick."""
        end = self.clock.now() + seconds
        while self.clock.now() < end:
            self.run(self.clock.advance(min(self.tick_s, end - self.clock.now())))
            self.run(self.ds.tick())
            silent = self.clock.now() - self.heard
            if self.holds and silent > self.limit + 2 * self.tick_s:
                # A verdict may be deferred once for a late tick: one tick more at most.
                assert self.ds.lease.halted, f"silent {silent:.3f} s, the arm not stopped"
        self.longest_silence = max(self.longest_silence, self.clock.now() - self.heard)

    @rule(age=st.floats(1.0, 5.0))
    def late_command(self, age: float) -> None:
        """A command sent before a silence of the page's (at least the worker's
        PAGE_SILENCE_MS, 1 s, earlier) arrives now: it never moves the arm."""
        assert not self.command(self.clock.now() - age)

    @invariant()
    def the_lease_is_kept_while_the_page_is_heard_within_the_grace(self) -> None:
        if self.longest_silence <= self.limit + self.grace:
            assert self.holds, (self.longest_silence, self.ds.state().lease_note)


TestStalledPage = StalledPage.TestCase
TestStalledPage.settings = settings(
    max_examples=80,
    stateful_step_count=20,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
