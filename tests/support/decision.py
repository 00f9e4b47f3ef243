"""A DecisionServer on the simulated PUMA in virtual time, for the safety tests."""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, TypeVar

from hypothesis.stateful import RuleBasedStateMachine

from telerobot.drivers.base import FloatArray
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits
from tests.support import TOKEN
from tests.support.clock import run_with_clock


class RecordingPuma(SimPuma):
    """The real simulated arm, noting every target that reaches the driver."""

    def __init__(self, **kw: object) -> None:
        super().__init__(**kw)  # type: ignore[arg-type]
        self.sent: list[FloatArray] = []

    async def _send_target(self, raw_target: FloatArray) -> None:
        self.sent.append(raw_target.copy())
        await super()._send_target(raw_target)


async def recording_puma(clock: ManualClock) -> RecordingPuma:
    """A simulated PUMA, initialised at qn in virtual time, nothing yet sent."""
    kin = Puma560Kinematics(tool_transform(0.1))
    robot = RecordingPuma(clock=clock, kinematics=kin, start_joints=NAMED_POSES["qn"])
    await robot.connect()
    await run_with_clock(clock, robot.initialize())
    robot.sent.clear()
    return robot


async def make(
    clock: ManualClock, limits: SafetyLimits | None = None
) -> tuple[DecisionServer, RecordingPuma]:
    robot = await recording_puma(clock)
    limits = limits or SafetyLimits()
    ds = DecisionServer(
        [ArmGuard("arm", 1, robot, Puma560Kinematics(tool_transform(0.1)), limits)],
        clock=clock,
        operator_token=TOKEN,
        limits=limits,
    )
    return ds, robot


def join_policy(ds: DecisionServer, name: str = "act-policy") -> Client:
    """A policy client, joined with a policy token issued for it (the operator token is
    refused with the POLICY flag)."""
    _, secret = ds.clients.policy_tokens.issue(name)
    return ds.join(name, secret, policy=True)


async def policy_let_drive(ds: DecisionServer, name: str = "act-policy") -> tuple[Client, Client]:
    """A policy holding the lease and let drive by "alice", a person: (policy, alice)."""
    policy = join_policy(ds, name)
    alice = ds.join("alice", TOKEN)
    await ds.take_lease(policy.id)
    await ds.resume_policy(alice.id)  # a person says go: a policy never starts by itself
    return policy, alice


T = TypeVar("T")


class OwnLoopMachine(RuleBasedStateMachine):
    """A Hypothesis state machine driving a DecisionServer on an event loop of its own
    (``run``), its leftover tasks (the simulated arm's reporter) cancelled at the end."""

    def __init__(self) -> None:
        super().__init__()
        self.loop = asyncio.new_event_loop()

    def run(self, coro: Coroutine[Any, Any, T]) -> T:
        return self.loop.run_until_complete(coro)

    def teardown(self) -> None:
        pending = asyncio.all_tasks(self.loop)
        for task in pending:
            task.cancel()
        self.loop.run_until_complete(asyncio.gather(*pending, return_exceptions=True))
        self.loop.close()
