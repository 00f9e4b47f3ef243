"""The LeRobot robot's one rule about the lease (telerobot/client/lerobot/arm.py,
``_take_back_if_free``), over generated sequences: it asks for the lease only while
nobody holds it, only with a TAKE (never a TAKE_OVER), never as a policy (the server
hands control back to a policy), and at most once every TAKE_BACK_S. The server judges
every request anyway (the lease is its); this is the client's manners."""

from __future__ import annotations

import itertools
from types import SimpleNamespace

from hypothesis import settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from telerobot.client.lerobot import arm as arm_module
from telerobot.client.lerobot.arm import TAKE_BACK_S, ArmOptions, TelerobotArm
from telerobot.protocol import messages as m

FLAGS = st.sampled_from(
    [0, m.StateFlags.SOMEONE_HAS_CONTROL, m.StateFlags.SOMEONE_HAS_CONTROL | m.StateFlags.ESTOP]
)


class TakeBack(RuleBasedStateMachine):
    @initialize(policy=st.booleans())
    def connect(self, policy: bool) -> None:
        self.now = 1000.0
        self.asked: list[tuple[float, int, int]] = []  # (when, action, flags then)
        self.mirror = SimpleNamespace(flags=m.StateFlags.SOMEONE_HAS_CONTROL)
        self.mirror.link = SimpleNamespace(
            lease=lambda action: self.asked.append((self.now, action, self.mirror.flags))
        )
        self.arm = TelerobotArm(ArmOptions(url="http://x/", token="t", policy=policy))
        self.clock = arm_module.time.monotonic
        arm_module.time.monotonic = lambda: self.now  # virtual time

    def teardown(self) -> None:
        arm_module.time.monotonic = self.clock

    @rule(flags=FLAGS)
    def a_state_arrives(self, flags: int) -> None:
        self.mirror.flags = flags

    @rule(dt=st.floats(0.0, 3.0))
    def time_passes(self, dt: float) -> None:
        self.now += dt

    @rule()
    def an_action_while_not_in_control(self) -> None:
        self.arm._take_back_if_free(self.mirror)  # type: ignore[arg-type]

    @invariant()
    def asked_only_for_a_free_lease_politely_and_seldom(self) -> None:
        if not hasattr(self, "asked"):
            return
        assert not (self.arm.options.policy and self.asked)
        for _when, action, flags in self.asked:
            assert action == m.LeaseAction.TAKE
            assert not flags & m.StateFlags.SOMEONE_HAS_CONTROL
        times = [when for when, _, _ in self.asked]
        assert all(b - a >= TAKE_BACK_S for a, b in itertools.pairwise(times))


TakeBack.TestCase.settings = settings(max_examples=200, stateful_step_count=40, deadline=None)
test_the_robot_asks_for_the_lease_only_when_free = TakeBack.TestCase
