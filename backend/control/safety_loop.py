"""The DecisionServer's own loop (docs/architecture.md, rule 15, "Safety owns its
loop"): every arm's force sensor subscribed, its samples judged on the event loop in
order like every command, and the dead-man's watchdog, a task of its own asking for
a verdict every ``tick_s``. So the force limit and the dead-man act whatever
transports (``/ws``, the priority channel, REST) are running, or none.

Apart from decision.py because it is plumbing (threads and a task), not a decision:
what a force sample or a tick does is the DecisionServer's (``on_force``, ``tick``),
handed in here."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable, Sequence

from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import Clock
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.limits import SafetyLimits

log = logging.getLogger("telerobot.server.control.decision")  # said as it always was


class SafetyLoop:
    def __init__(
        self,
        arms: Sequence[ArmGuard],
        clock: Clock,
        limits: SafetyLimits,
        on_force: Callable[[ForceSample, ArmGuard], None],
        tick: Callable[[], Awaitable[None]],
    ) -> None:
        self.arms = arms
        self.clock = clock
        self.limits = limits
        self.on_force = on_force
        self.tick = tick
        self._watchdog: asyncio.Task[None] | None = None

    def start(self) -> None:
        """Subscribe to the force sensors and start the dead-man watchdog (on the
        running event loop). Force samples arrive on the sensor's thread and are
        judged on the loop, in order, like every command."""
        loop = asyncio.get_running_loop()
        for guard in self.arms:
            if guard.force is None or guard.unsubscribe is not None:
                continue

            def from_sensor_thread(sample: ForceSample, guard: ArmGuard = guard) -> None:
                with contextlib.suppress(RuntimeError):  # the loop is closing
                    loop.call_soon_threadsafe(self.on_force, sample, guard)

            guard.unsubscribe = guard.force.subscribe(from_sensor_thread)
        if self._watchdog is None:
            self._watchdog = loop.create_task(self._run_watchdog(), name="dead-man")

    async def stop(self) -> None:
        for guard in self.arms:
            if guard.unsubscribe is not None:
                guard.unsubscribe()
                guard.unsubscribe = None
        if self._watchdog is not None:
            self._watchdog.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watchdog
            self._watchdog = None

    async def _run_watchdog(self) -> None:
        while True:
            await self.clock.sleep(self.limits.tick_s)
            try:
                await self.tick()
            except Exception:  # a failing check must not end the watchdog
                log.exception("dead-man check failed")
