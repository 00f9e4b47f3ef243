"""A priority channel (backend/realtime/priority.py) on the simulated PUMA, in this
process, with a force sensor whose samples the test sends."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import MonotonicClock
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.server.control.decision import DecisionServer
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.priority import PriorityChannel
from telerobot.server.telemetry.stats import Telemetry
from tests.support import TOKEN


class FakeSensor:
    """A force sensor whose samples the test sends (from its own thread, as a real
    sensor's thread would)."""

    def __init__(self) -> None:
        self.callbacks: list[Callable[[ForceSample], None]] = []
        self.seq = 0

    def subscribe(
        self, callback: Callable[[ForceSample], None], *, first: bool = False
    ) -> Callable[[], None]:
        self.callbacks.insert(0 if first else len(self.callbacks), callback)
        return lambda: self.callbacks.remove(callback)

    def emit(self) -> None:
        self.seq += 1
        sample = ForceSample(self.seq, time.monotonic(), (0.0, 0.0, 1.0, 0.0, 0.0, 0.0))
        for callback in list(self.callbacks):
            callback(sample)


async def build_channel(
    sensor: FakeSensor | None = None, **limits: Any
) -> tuple[PriorityChannel, RealtimeHub]:
    clock = MonotonicClock()
    kinematics = Puma560Kinematics(tool_transform(0.1))
    robot = SimPuma(clock=clock, kinematics=kinematics, start_joints=NAMED_POSES["qz"])
    decision = DecisionServer(robot, kinematics=kinematics, clock=clock, operator_token=TOKEN)
    hub = RealtimeHub(robot, decision, None, Telemetry(), clock)
    hub.start()
    channel = PriorityChannel("127.0.0.1", 0, hub, decision, sensor, **limits)  # type: ignore[arg-type]
    channel.start()
    return channel, hub
