from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Iterator
from typing import TypeVar

import pytest
from fastapi.testclient import TestClient

from drivers.clock import ManualClock


def pytest_configure() -> None:
    # Tokens and certificates that servers under test create go to a throw-away
    # folder, never into the developer's ~/.config (subprocesses inherit this).
    import os
    import tempfile

    os.environ.setdefault("TELEROBOT_STATE_DIR", tempfile.mkdtemp(prefix="telerobot-test-state-"))
    # Servers under test run without the media worker unless a test turns it on
    # (it renders and encodes 2×1280×720 at 30 fps: the video tests say so explicitly).
    os.environ.setdefault("TELEROBOT_VIDEO", "false")
    # Many servers run side by side: each takes a free port for its priority channel.
    os.environ.setdefault("TELEROBOT_PRIORITY_PORT", "0")
    # …and no 3D view unless a test asks for it (viser starts its own server).
    os.environ.setdefault("TELEROBOT_VIEWER", "false")
    os.environ.setdefault("TELEROBOT_VIEWER_PORT", "0")


T = TypeVar("T")


@pytest.fixture(autouse=True)
def _no_realtime_test_process() -> Iterator[None]:
    """A test that leaves this process in a realtime scheduling class fails here, by name:
    every server and browser started later would inherit it, and one spinning at
    SCHED_FIFO 99 freezes the machine (and CI with it) instead of failing a test."""
    import os

    yield
    policy = os.sched_getscheduler(0)
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        pytest.fail(f"this test left the test process in realtime scheduling ({policy})")


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


@pytest.fixture
def client() -> Iterator[TestClient]:
    """The app on the simulation (at qz), in process, once the arm is READY."""
    from backend.app import create_app
    from backend.settings import Settings
    from tests.test_decision import TOKEN

    with TestClient(
        create_app(Settings(home_pose="qz", operator_token=TOKEN)), base_url="http://localhost"
    ) as tc:
        deadline = time.monotonic() + 10
        while (
            tc.get("/api/v1/robot/state").json()["status"] != "READY"
            and time.monotonic() < deadline
        ):
            time.sleep(0.01)
        yield tc
