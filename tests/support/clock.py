"""Virtual time for async work: the clock advances only when the test says so."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import TypeVar

from telerobot.drivers.clock import ManualClock

T = TypeVar("T")


async def run_with_clock(
    clock: ManualClock, work: Awaitable[T], step: float = 0.05, limit: float = 60.0
) -> T:
    """Await ``work`` while advancing virtual time in ``step`` s steps (at most ``limit`` s)."""
    task = asyncio.ensure_future(work)
    elapsed = 0.0
    while not task.done():
        if elapsed > limit:
            task.cancel()
            raise AssertionError(f"still running after {limit} s of virtual time")
        await clock.advance(step)
        elapsed += step
    return task.result()
