"""``until``: wait for a condition with a deadline, saying what was waited for."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable


def _timed_out(what: str | Callable[[], str], timeout: float) -> AssertionError:
    said = what() if callable(what) else what
    return AssertionError(f"timed out after {timeout} s" + (f": {said}" if said else ""))


def until(
    condition: Callable[[], object],
    timeout: float = 10.0,
    what: str | Callable[[], str] = "",
    poll: float = 0.005,
) -> None:
    """Poll ``condition`` until it is true; after ``timeout`` s fail, saying ``what``
    (a callable is asked only then, e.g. for what a page said)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise _timed_out(what, timeout)
        time.sleep(poll)


async def until_async(
    condition: Callable[[], object],
    timeout: float = 10.0,
    what: str | Callable[[], str] = "",
    poll: float = 0.002,
) -> None:
    """``until`` for a test on an event loop: the loop runs while it waits."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise _timed_out(what, timeout)
        await asyncio.sleep(poll)
