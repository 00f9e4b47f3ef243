"""The supervision's one rule over generated sequences (Hypothesis' stateful testing):
a policy's command moves the arm only if a person's resume or hand-back came after the
last stop event (the e-stop, a force stop, a pause, a lease lapse, a policy joining,
taking the lease or leaving). docs/architecture.md, "Supervised autonomy".

The real DecisionServer on the simulated PUMA in virtual time, driven the way the page,
REST and the LeRobot plugin drive it: takes and releases, pauses and resumes, e-stops and
resets (from the person and from the policy), force stops, dead-man lapses, and the
policy and the person reconnecting. The model knows only when a person said go and when
something stopped; the server may refuse more than the model allows (that is not this
test's concern), never less.

``TELEROBOT_RULE_EXAMPLES`` sets how many sequences: 1,000 here (about 12 s; a mutant
that hands back with the e-stop latched is found within them), 10,000 for the figure
in docs/PERFORMANCE.md (``--timeout=0``: longer than a test's limit).
"""

from __future__ import annotations

import asyncio
import os

import numpy as np
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import initialize, invariant, precondition, rule

from telerobot.drivers.base import ForceSample, TelerobotError
from telerobot.drivers.clock import ManualClock
from telerobot.server.control.autonomy import Mode, ReleaseTo
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed
from tests.support import TOKEN
from tests.support.decision import OwnLoopMachine, RecordingPuma, make

STEP = np.array([0.002, 0, 0, 0, 0, 0])
EXAMPLES = int(os.environ.get("TELEROBOT_RULE_EXAMPLES", "1000"))
HIGH_N = 80.0  # above the force limit
LOW_N = 0.0


class Supervision(OwnLoopMachine):
    def __init__(self) -> None:
        super().__init__()
        self.clock = ManualClock()
        self.ds: DecisionServer
        self.robot: RecordingPuma
        self.ds, self.robot = self.run(make(self.clock))
        _, self.secret = self.ds.clients.policy_tokens.issue("act-policy")
        self.policy: Client | None = None
        self.person: Client = self.ds.join("alice", TOKEN)
        # The model: a person said go since the last stop event.
        self.go = False
        self.force_limited = False
        self.moves_by_policy = 0

    # ------------------------------------------------------------ helpers
    def attempt(self, coro) -> bool:  # type: ignore[no-untyped-def]
        """Whether the call went through (a refusal is a TelerobotError, never anything else)."""
        try:
            self.run(coro)
        except TelerobotError:
            return False
        return True

    def stop_event(self) -> None:
        self.go = False

    def lease_changed_by_itself(self, before: str | None) -> None:
        if before is not None and self.ds.lease_holder != before:
            self.stop_event()  # a lapse

    @initialize(
        start=st.sampled_from(
            ["nobody", "a policy holds control", "a policy drives", "a person corrects"]
        ),
        release_to=st.sampled_from(list(ReleaseTo)),
    )
    def begin(self, start: str, release_to: ReleaseTo) -> None:
        """Most sequences start where a policy is supervised: the states worth exploring
        (a random walk from nothing seldom gets there and on)."""
        self.ds.supervision.release_to = release_to
        if start == "nobody":
            return
        self.policy_joins()
        self.policy_takes(force=False)
        if start in ("a policy drives", "a person corrects"):
            self.person_resumes()
            assert self.go
        if start == "a person corrects":
            self.person_takes(force=False)

    # ------------------------------------------------------------ the policy
    @rule()
    def policy_joins(self) -> None:
        """A policy joins, or reconnects (a restarted rollout): the old one leaves first."""
        before = self.ds.lease_holder
        if self.policy is not None:
            self.run(self.ds.leave(self.policy.id))
            self.stop_event()
        self.lease_changed_by_itself(before)
        self.policy = self.ds.join("act-policy", self.secret, policy=True)
        self.stop_event()

    @precondition(lambda self: self.policy is not None)
    @rule(force=st.booleans())
    def policy_takes(self, force: bool) -> None:
        assert self.policy is not None
        had = self.ds.lease_holder == self.policy.id
        if self.attempt(self.ds.take_lease(self.policy.id, force=force)) and not had:
            self.stop_event()

    @precondition(lambda self: self.policy is not None)
    @rule()
    def policy_releases(self) -> None:
        assert self.policy is not None
        before = self.ds.lease_holder
        self.attempt(self.ds.release_lease(self.policy.id))
        self.lease_changed_by_itself(before)

    @precondition(lambda self: self.policy is not None)
    @rule(joint=st.sampled_from([True, False]))
    def policy_drives(self, joint: bool) -> None:
        assert self.policy is not None
        self.run(self.clock.advance(0.02))
        sent = len(self.robot.sent)
        if joint:
            self.attempt(self.ds.joint_increment(self.policy.id, STEP))
        else:
            self.attempt(
                self.ds.cartesian_increment(self.policy.id, np.array([0, 0, 0.001]), np.zeros(3))
            )
        if len(self.robot.sent) > sent:
            self.moves_by_policy += 1
            # The rule.
            assert self.go, "a policy moved the arm with no person's go since the last stop"
            assert not self.ds.state().estop

    @precondition(lambda self: self.policy is not None)
    @rule(what=st.sampled_from(["reset", "resume", "pause"]))
    def policy_tries_a_persons_action(self, what: str) -> None:
        assert self.policy is not None
        act = {"reset": self.ds.reset, "resume": self.ds.resume_policy, "pause": self.ds.pause}
        try:
            self.run(act[what](self.policy.id))
        except NotAllowed:
            return
        raise AssertionError(f"a policy's {what} went through")

    # ------------------------------------------------------------ the person
    @rule(force=st.booleans())
    def person_takes(self, force: bool) -> None:
        self.attempt(self.ds.take_lease(self.person.id, force=force))

    @rule()
    def person_releases(self) -> None:
        """The person lets go: from a correction, a hand-back (a go, unless the e-stop is
        latched or autonomy_release says pause)."""
        correcting = (
            self.ds.autonomy.mode is Mode.CORRECTING and self.ds.lease_holder == self.person.id
        )
        before = self.ds.lease_holder
        estop = self.ds.state().estop
        if not self.attempt(self.ds.release_lease(self.person.id)):
            return
        if correcting and self.ds.lease_holder != before:
            if estop or self.ds.supervision.release_to is ReleaseTo.PAUSE:
                self.stop_event()  # handed back, but paused
            else:
                self.go = True
        else:
            self.lease_changed_by_itself(before)

    @rule()
    def person_pauses(self) -> None:
        before = self.ds.lease_holder
        if self.attempt(self.ds.pause(self.person.id)):
            self.stop_event()
        self.lease_changed_by_itself(before) if before == self.person.id else None

    @rule()
    def person_resumes(self) -> None:
        if self.attempt(self.ds.resume_policy(self.person.id)):
            self.go = True

    @rule()
    def person_resets(self) -> None:
        self.attempt(self.ds.reset(self.person.id))

    @rule()
    def person_reconnects(self) -> None:
        before = self.ds.lease_holder
        self.run(self.ds.leave(self.person.id))
        self.lease_changed_by_itself(before)
        self.person = self.ds.join("alice", TOKEN)

    # ------------------------------------------------------------ stops
    @rule(by_policy=st.booleans())
    def estop(self, by_policy: bool) -> None:
        who = self.policy.id if by_policy and self.policy is not None else None
        self.run(self.ds.estop(who, "e-stop pressed"))
        self.stop_event()

    @rule(high=st.booleans())
    def force(self, high: bool) -> None:
        value = HIGH_N if high else LOW_N

        async def sample() -> None:  # on the loop, as the sensor's samples arrive
            self.ds.on_force(
                ForceSample(1, self.clock.now(), (value, 0.0, 0.0, 0.0, 0.0, 0.0)), self.ds.arms[0]
            )
            await asyncio.sleep(0)  # the stop it starts

        self.run(sample())
        if high and not self.force_limited:
            self.stop_event()
        self.force_limited = self.ds.arms[0].force_limited

    @rule()
    def everyone_goes_silent(self) -> None:
        """Past the dead-man and its grace: the holder's lease lapses."""
        before = self.ds.lease_holder
        limits = self.ds.limits
        self.run(self.clock.advance(limits.deadman_timeout_s + limits.lease_grace_s + 6.0))
        for _ in range(3):
            self.run(self.ds.tick())
        self.lease_changed_by_itself(before)

    # ------------------------------------------------------------ always
    @invariant()
    def a_policy_that_may_drive_was_let_drive(self) -> None:
        if self.ds.autonomy.may_drive:
            assert self.go, "the server would let the policy drive with no person's go"

    @invariant()
    def the_policy_keeps_sending(self) -> None:
        """A policy sends all the time (30 Hz): after every step, it tries once more."""
        if self.policy is not None:
            self.policy_drives(joint=True)


TestSupervisionRule = Supervision.TestCase
TestSupervisionRule.settings = settings(
    max_examples=EXAMPLES,
    stateful_step_count=30,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
