"""The fixtures every test module may ask for by name (the rest of the harness is in
tests/support/, which test modules import; they import nothing from each other)."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import time
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from playwright.sync_api import Browser, Playwright

from tests.support import TOKEN


def pytest_configure() -> None:
    # Tokens and certificates that servers under test create go to a throw-away
    # folder, never into the developer's ~/.config (subprocesses inherit this).
    if "TELEROBOT_STATE_DIR" not in os.environ:
        state = tempfile.mkdtemp(prefix="telerobot-test-state-")
        os.environ["TELEROBOT_STATE_DIR"] = state
        # …removed when this process ends (each xdist worker made its own; a run left
        # one per worker in /tmp before)
        atexit.register(shutil.rmtree, state, ignore_errors=True)
    # Servers under test run without the media worker unless a test turns it on
    # (it renders and encodes 2×1280×720 at 30 fps: the video tests say so explicitly).
    os.environ.setdefault("TELEROBOT_VIDEO", "false")
    # Many servers run side by side: each takes a free port for its priority channel.
    os.environ.setdefault("TELEROBOT_PRIORITY_PORT", "0")
    # …and no 3D view unless a test asks for it (viser starts its own server).
    os.environ.setdefault("TELEROBOT_VIEWER", "false")
    os.environ.setdefault("TELEROBOT_VIEWER_PORT", "0")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The browser tests last (a stable sort: each module's stay in order). Playwright's
    sync API runs an event loop in this thread from the session's Chromium's start to
    the session's end, and an async test after it could not run its own."""
    items.sort(
        key=lambda item: (
            item.get_closest_marker("browser") is not None
            or "browser" in getattr(item, "fixturenames", ())
        )
    )


@pytest.fixture(autouse=True)
def _no_realtime_test_process() -> Iterator[None]:
    """A test that leaves this process in a realtime scheduling class fails here, by name:
    every server and browser started later would inherit it, and one spinning at
    SCHED_FIFO 99 freezes the machine (and CI with it) instead of failing a test."""
    yield
    policy = os.sched_getscheduler(0)
    if policy in (os.SCHED_FIFO, os.SCHED_RR):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        pytest.fail(f"this test left the test process in realtime scheduling ({policy})")


@pytest.fixture
def client() -> Iterator[TestClient]:
    """The app on the simulation (at qz), in process, once the arm is READY."""
    from telerobot.server.app import create_app
    from telerobot.server.settings import Settings

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


@pytest.fixture(scope="session")
def playwright() -> Iterator[Playwright]:
    """Playwright's sync API, once for the session (a second one in the same thread is
    refused: it runs an event loop there)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        yield p


@pytest.fixture(scope="session")
def browser(playwright: Playwright) -> Iterator[Browser]:
    """Debian's Chromium, one for the whole session: each test opens its own pages
    (closed after it by ``_pages_closed``)."""
    from tests.support.browser import chromium

    with chromium(playwright) as b:
        yield b


@pytest.fixture(autouse=True)
def _pages_closed(request: pytest.FixtureRequest) -> Iterator[None]:
    """Whatever a browser test left open (a failed test never reaches its page.close())
    is closed after it: a page left playing video would take the CPU of every test after
    it in the session's one browser."""
    yield
    if "browser" in request.fixturenames:
        for context in request.getfixturevalue("browser").contexts:
            context.close()


@pytest.fixture(scope="module")
def server(request: pytest.FixtureRequest) -> Iterator[str]:
    """The operator page's server, one per module; its URL. The simulation with video
    (tests.support.browser.ENV) unless the module sets ``SERVER_ENV`` (e.g. NO_VIDEO)."""
    from tests.support.browser import ENV, chromium_or_fail
    from tests.support.servers import serving

    chromium_or_fail()
    with serving(getattr(request.module, "SERVER_ENV", ENV)) as base:
        yield base
