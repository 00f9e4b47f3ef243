"""A page watching through the media server, in Debian's Chromium against a
real `telerobot serve --media-server janus`: an observer's page takes Janus's offer and
shows the stereo video; the operator's page on the same server stays on the direct path."""

from __future__ import annotations

import shutil
from collections.abc import Iterator

import httpx
import pytest
from playwright.sync_api import Browser

from tests.support import TOKEN, until
from tests.support.browser import (
    ENV,
    open_page,
    wait,
)
from tests.support.servers import serving

pytestmark = pytest.mark.browser

SERVER_ENV = {
    **ENV,
    "TELEROBOT_OPERATOR_TOKEN": TOKEN,
    "TELEROBOT_PRIORITY_PORT": "0",
    "TELEROBOT_MEDIA_SERVER": "janus",
}


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    if shutil.which("janus") is None:
        pytest.fail("Debian's janus is missing: `make test` installs it (make media-server-deps)")
    with serving(SERVER_ENV) as base:
        yield base


def stats(base: str) -> dict[str, object]:
    reply = httpx.get(
        base + "api/v1/video", headers={"Authorization": f"Bearer {TOKEN}"}, timeout=10
    )
    result: dict[str, object] = reply.json()["stats"]
    return result


def test_an_observers_page_watches_through_janus_and_the_operators_directly(
    browser: Browser, server: str
) -> None:
    observer, errors = open_page(browser, server, token="")  # waits for > 10 frames
    relay = stats(server)["relay"]
    assert isinstance(relay, dict) and relay["viewers"] == 1, relay
    assert stats(server)["viewer_count"] == 0  # none of the robot's own peers
    frames = observer.evaluate("window.telerobot.view.frames")
    wait(observer, f"window.telerobot.view.frames > {frames + 20}")  # and it goes on
    operator, op_errors = open_page(browser, server)
    # The operator: direct. (Counted once its peer is the server's; on a busy machine a
    # page may still be replacing a first peer that stalled when its frames came.)
    until(lambda: stats(server)["viewer_count"] == 1, what="the operator's direct peer")
    assert isinstance(relay := stats(server)["relay"], dict) and relay["viewers"] == 1
    operator.close()
    observer.close()
    video_errors = [e for e in errors + op_errors if "video" in e.lower()]
    assert not video_errors, video_errors
