"""The connection HUD (web/src/ui/connection-hud.ts) in a real browser (Debian's Chromium)
against a real ``telerobot serve``: on the loopback link it is green with the video's
frame rate, the round trip and the force age; it turns red, saying why, when the server
stops the force stream and when it drops this page's video peer, and comes back by
itself (the freeze counted)."""

from __future__ import annotations

import re
import time
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, Page

from tests.webpage import (  # noqa: F401  (browser and server are fixtures)
    TOKEN,
    browser,
    drop_video_peer,
    open_page,
    server,
    wait,
)

pytestmark = pytest.mark.browser

AUTH = {"Authorization": f"Bearer {TOKEN}"}
HUD = "window.telerobot.hud"


def row_is(key: str, condition: str) -> str:
    """A page expression: the HUD's `key` row exists and `condition` holds for it (`r`)."""
    return f"(() => {{ const r = {HUD}.rows.find((x) => x.key === '{key}'); return !!r && ({condition}); }})()"


def rows(page: Page) -> dict[str, dict[str, Any]]:
    found: list[dict[str, Any]] = page.evaluate(f"{HUD}.rows")
    return {r["key"]: r for r in found}


def said(page: Page) -> str:
    return str(page.evaluate(f"JSON.stringify({{ level: {HUD}.level, rows: {HUD}.rows }})"))


def hud_wait(page: Page, expression: str, timeout: float) -> None:
    """Wait for ``expression``; on timeout, say what the HUD said."""
    try:
        wait(page, expression, timeout)
    except AssertionError as e:
        raise AssertionError(f"{e}\nthe HUD: {said(page)}") from None


def test_the_hud_is_green_on_loopback_and_turns_red_with_the_reason(
    browser: Browser, server: str
) -> None:
    t0 = time.monotonic()
    page, errors = open_page(browser, server)
    # The loopback link: all green (once the freezes of the page's start-up, compiling
    # and loading on this loaded machine, are out of the HUD's 10 s window).
    # (And the video's bitrate known: it needs two of getStats' samples, which a
    # loaded machine may not have taken yet when everything else is already green.)
    hud_wait(
        page,
        f"{HUD}.level === 'ok' && " + row_is("video", "/kbit\\/s/.test(r.text)"),
        timeout=20_000,
    )
    r = rows(page)
    assert re.match(r"^\d+ fps · \d+ kbit/s · full \d+×\d+$", r["video"]["text"]), said(page)
    assert re.match(r"^video [\d.]+ ms · ping [\d.]+ ms$", r["rtt"]["text"]), said(page)
    assert re.match(r"^[\d.]+ ms$", r["force"]["text"]), said(page)
    assert r["clock"]["text"].endswith((" ms", " s")), said(page)
    # Drawn over the video's corner, in the window (not below the fold), green.
    hud = page.locator("#hud")
    assert hud.get_attribute("class") == "hud-ok"
    assert "connection ok" in hud.inner_text()
    assert re.search(r"video\s+\d+ fps", hud.inner_text())
    b, stage = hud.bounding_box(), page.locator("#stage").bounding_box()
    assert b is not None and stage is not None
    assert stage["x"] <= b["x"] and b["x"] + b["width"] <= stage["x"] + stage["width"]
    assert stage["y"] <= b["y"] and b["y"] + b["height"] <= 900  # the viewport's height

    # The force stream stops on the server: the newest sample ages, red within ~0.5 s.
    assert httpx.post(server + "api/v1/force/stop", headers=AUTH).status_code == 200
    try:
        hud_wait(page, f"{HUD}.level === 'red' && " + row_is("force", "r.level === 'red'"), 5_000)
        text = rows(page)["force"]["text"]
        assert re.match(r"^(\d+ ms|no new sample for [\d.]+ s) \(> 200 ms\)$", text), said(page)
        assert "force age" in page.evaluate(f"{HUD}.reason")
        assert hud.get_attribute("class") == "hud-red"
        assert "connection bad" in hud.inner_text()
    finally:
        assert httpx.post(server + "api/v1/force/start", headers=AUTH).status_code == 200
    hud_wait(page, row_is("force", "r.level === 'ok'"), 5_000)

    # The server drops this page's video peer (as a crashed or restarted media worker
    # would): no new frame, red with how long, until the page re-negotiates by itself.
    drop_video_peer(page, server)
    hud_wait(
        page,
        f"{HUD}.level === 'red' && "
        + row_is(
            "video", "r.level === 'red' && /^(frozen: no new frame for|no video peer)/.test(r.text)"
        ),
        5_000,
    )
    assert "video: " in page.evaluate(f"{HUD}.reason")
    # Back by itself: frames again, the video row green, the freeze counted (amber).
    hud_wait(page, row_is("video", "r.level === 'ok'"), 20_000)
    hud_wait(
        page,
        row_is("freezes", "r.level !== 'ok' && /^\\d+ in 10 s \\(longest/.test(r.text)"),
        5_000,
    )
    assert errors == []
    page.close()
    assert time.monotonic() - t0 < 40
