"""The status page in a real browser: Debian's Chromium driven by Playwright."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from playwright.sync_api import Browser, sync_playwright

from tests.servers import telerobot

CHROMIUM = Path("/usr/bin/chromium")
pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if not CHROMIUM.exists():
        if os.environ.get("TELEROBOT_SKIP_BROWSER") == "1":
            pytest.skip("TELEROBOT_SKIP_BROWSER=1 and no /usr/bin/chromium")
        pytest.fail(
            "Debian's chromium is missing: `make test` installs it (apt-get install chromium)"
        )
    with sync_playwright() as p:
        b = p.chromium.launch(
            executable_path=str(CHROMIUM),
            args=[
                "--no-sandbox",
                "--disable-gpu",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
            ],
        )
        yield b
        b.close()


def test_status_page_shows_the_robot_moving_then_ready(browser: Browser, tmp_path: Path) -> None:
    with telerobot("serve", "--http-port", "0", wait_for=r"(http://localhost:\d+/)") as (_, m):
        page = browser.new_page()
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(m.group(1) + "status")
        status = page.locator("#status")
        # The sim starts at qz and initialises to qn, which takes ~3.6 s.
        page.wait_for_function(
            "document.getElementById('status').textContent === 'MOVING'", timeout=10_000
        )
        page.wait_for_function(
            "document.getElementById('status').textContent === 'READY'", timeout=20_000
        )
        assert status.get_attribute("class") == "status READY"
        assert page.locator("#driver").text_content() == "sim-puma560"
        assert page.locator("#j2").text_content() == "-180.00"  # qn's joint 3
        assert page.locator("#f2").text_content() not in ("", None)  # force values stream in
        page.locator("#estop").click()
        page.wait_for_function(
            "document.getElementById('safety').textContent.includes('E-STOP latched')"
        )
        page.screenshot(path=os.environ.get("TELEROBOT_SCREENSHOT", str(tmp_path / "status.png")))
        assert errors == []
        page.close()
