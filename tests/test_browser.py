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


def test_the_api_docs_render_with_no_internet(browser: Browser) -> None:
    with telerobot("serve", "--http-port", "0", wait_for=r"(http://localhost:\d+/)") as (_, m):
        base = m.group(1)
        page = browser.new_page()
        outside: list[str] = []

        def only_this_server(route) -> None:  # type: ignore[no-untyped-def]
            if route.request.url.startswith(base):
                route.continue_()
            else:  # a CDN, or anything else: the page must not need it
                outside.append(route.request.url)
                route.abort()

        page.route("**/*", only_this_server)
        page.goto(base + "docs")
        page.wait_for_selector(".swagger-ui .info .title", timeout=20_000)
        assert "Telerobot" in (page.locator(".swagger-ui .info .title").text_content() or "")
        page.get_by_text("/api/v1/safety/estop", exact=True).wait_for(timeout=20_000)
        assert outside == []
