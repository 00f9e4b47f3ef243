"""A priority channel (backend/realtime/priority.py) on the simulated PUMA, in this
process, with a force sensor whose samples the test sends."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable, Coroutine
from typing import Any, TypeVar

from telerobot.client.master.link import Reply
from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import MonotonicClock
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.priority import PriorityChannel
from telerobot.server.realtime.priority_connection import PriorityClient
from telerobot.server.telemetry.stats import Telemetry
from tests.support import TOKEN, until

T = TypeVar("T")


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
    decision = DecisionServer(
        [ArmGuard("arm", 1, robot, kinematics, SafetyLimits(), sensor)],  # type: ignore[arg-type]
        clock=clock,
        operator_token=TOKEN,
    )
    hub = RealtimeHub(decision, Telemetry(), clock)
    hub.start()
    channel = PriorityChannel("127.0.0.1", 0, hub, decision, **limits)
    channel.start()
    return channel, hub


class Recorder:
    def __init__(self) -> None:
        self.forces: list[tuple[ForceSample, float]] = []
        self.replies: list[Reply] = []
        self.lock = threading.Lock()

    def force(self, sample: ForceSample, at: float) -> None:
        self.forces.append((sample, at))

    def reply(self, r: Reply) -> None:
        with self.lock:
            self.replies.append(r)

    def reply_to(self, seq: int) -> Reply:
        until(
            lambda: any(r.fields.get("seq") == seq for r in list(self.replies)),
            what=lambda: (
                f"no reply to #{seq}; the last replies: {list(self.replies)[-5:]}"
                f" (forces received: {len(self.forces)})"
            ),
        )
        return next(r for r in list(self.replies) if r.fields.get("seq") == seq)


class ChannelServer:
    """A channel on an event loop in a thread of its own, like the server's."""

    def __init__(self, **limits: Any) -> None:
        self.sensor = FakeSensor()
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        self.channel, self.hub = self.call(build_channel(self.sensor, **limits))
        self.port = self.channel.port

    def call(self, work: Coroutine[Any, Any, T]) -> T:
        return asyncio.run_coroutine_threadsafe(work, self.loop).result(10)

    def client(self, peer_port: int) -> PriorityClient:
        """The server's side of a connection, by the client's port."""
        until(lambda: any(c.peer.endswith(f":{peer_port}") for c in list(self.channel.clients)))
        return next(c for c in list(self.channel.clients) if c.peer.endswith(f":{peer_port}"))

    def close(self) -> None:
        self.call(self.channel.stop())
        self.call(self.hub.stop())
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()
