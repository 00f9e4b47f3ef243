"""Injected time (docs/architecture.md, rule 10).

Every driver, watchdog and motion profile takes a ``Clock`` so that tests can run
them faster than real time, with no sleeps: ``ManualClock.advance`` moves virtual
time forward and wakes exactly the sleepers whose deadline has passed, in order.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import time
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float:
        """Seconds on a monotonic time base."""
        ...

    async def sleep(self, seconds: float) -> None: ...


class MonotonicClock:
    """Real time: ``time.monotonic`` and ``asyncio.sleep``."""

    def now(self) -> float:
        return time.monotonic()

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))


class ManualClock:
    """Virtual time for tests; only ``advance`` makes it move."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = start
        self._sleepers: list[tuple[float, int, asyncio.Future[None]]] = []
        self._order = itertools.count()

    def now(self) -> float:
        return self._now

    async def sleep(self, seconds: float) -> None:
        future: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._sleepers, (self._now + max(0.0, seconds), next(self._order), future))
        await future

    async def advance(self, seconds: float) -> None:
        """Move time forward by ``seconds``, running every sleeper that comes due on the way."""
        target = self._now + seconds
        while True:
            await _let_tasks_run()
            self._sleepers = [s for s in self._sleepers if not s[2].done()]
            heapq.heapify(self._sleepers)
            if not self._sleepers or self._sleepers[0][0] > target:
                break
            deadline, _, future = heapq.heappop(self._sleepers)
            self._now = max(self._now, deadline)
            future.set_result(None)
        self._now = target
        await _let_tasks_run()


async def _let_tasks_run(rounds: int = 8) -> None:
    # A woken task may await a few futures before it sleeps again; give it those turns.
    for _ in range(rounds):
        await asyncio.sleep(0)
