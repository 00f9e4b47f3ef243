"""The status page in a real browser: Debian's Chromium driven by Playwright."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from playwright.sync_api import Browser

from tests.support.servers import serving

pytestmark = pytest.mark.browser


def test_status_page_shows_the_robot_moving_then_ready(browser: Browser, tmp_path: Path) -> None:
    with serving({"TELEROBOT_SIM_STARTS_AT_HOME": "false"}, ready=False) as base:
        page = browser.new_page()
        errors: list[str] = []
        page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        page.goto(base + "status")
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
    with serving(ready=False) as base:
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
