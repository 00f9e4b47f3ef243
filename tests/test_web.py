"""The operator client in a real browser (Debian's Chromium through Playwright)
against the real server on the simulation, video included."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page, sync_playwright

from bench.browser import ARGS  # the same Chromium flags as the browser benchmark
from tests.servers import telerobot
from tests.test_browser import CHROMIUM

# Not in the default `make test` yet: inside the full suite on this GPU-less 2-core
# machine these pages stop receiving frames (they pass run alone: `make test-web`).
# Issue 5 stays open until they are stable here.
pytestmark = [pytest.mark.browser, pytest.mark.heavy_browser]
TOKEN = "web-test-operator-token-0123456789"
ENV = {
    "TELEROBOT_VIDEO": "true",
    # 2×640×360 at 20 fps (the timecode needs 520 px of width): this 2-core machine
    # also runs the server and a software GPU.
    "TELEROBOT_VIDEO_WIDTH": "640",
    "TELEROBOT_VIDEO_HEIGHT": "360",
    "TELEROBOT_VIDEO_FPS": "20",
    "TELEROBOT_OPERATOR_TOKEN": TOKEN,
    "TELEROBOT_HOME_POSE": "qn",
    # The longest dead-man the spec allows (stop within 200 ms): a software-rendered
    # page on this loaded 2-core machine can stall its timers for 150 ms.
    "TELEROBOT_DEADMAN_TIMEOUT_S": "0.18",
}
SHOTS = Path(__file__).resolve().parents[1] / "docs" / "img"

# A gamepad the test holds: standard mapping, R1 (button 5) is the dead-man.
FAKE_GAMEPAD = """
window.__pad = { axes: [0, 0, 0, 0], pressed: new Set() };
navigator.getGamepads = () => [{
  id: "scripted", index: 0, connected: true, mapping: "standard", timestamp: performance.now(),
  axes: window.__pad.axes,
  buttons: Array.from({ length: 17 }, (_, i) => ({ pressed: window.__pad.pressed.has(i), touched: false, value: window.__pad.pressed.has(i) ? 1 : 0 })),
}];
"""


def _serve() -> Iterator[str]:
    if not CHROMIUM.exists():
        pytest.fail("Debian's chromium is missing: `make test` installs it")
    with telerobot("serve", "--http-port", "0", wait_for=r"(http://localhost:\d+/)", env=ENV) as (
        _,
        m,
    ):
        base = m.group(1)
        deadline = time.monotonic() + 30
        while httpx.get(base + "api/v1/robot/state").json()["status"] != "READY":
            assert time.monotonic() < deadline
            time.sleep(0.2)
        yield base


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    yield from _serve()


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        yield b
        b.close()


def open_page(browser: Browser, base: str, token: str = TOKEN) -> tuple[Page, list[str]]:
    page = browser.new_page(viewport={"width": 1500, "height": 900})
    errors: list[str] = []
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.add_init_script(FAKE_GAMEPAD)
    page.goto(base + (f"?token={token}" if token else ""))
    page.wait_for_function(
        "window.telerobot && window.telerobot.view.frames > 10", timeout=60_000, polling=100
    )
    return page, errors


def wait(page: Page, expression: str, timeout: float = 10_000) -> None:
    """Wait for ``expression`` in the page; on timeout, say what the page said."""
    try:
        page.wait_for_function(expression, timeout=timeout, polling=100)
    except Exception:
        said = page.locator("#messages").inner_text()
        flags = page.evaluate("window.telerobot.state && window.telerobot.state.flags")
        raise AssertionError(
            f"{expression} never held; flags {flags}; page messages:\n{said}"
        ) from None


def target(server: str) -> list[float]:
    return httpx.get(server + "api/v1/robot/state").json()["target_joints"]


def test_gamepad_dead_man_drives_releasing_stops_estop_stops_observer_cannot(
    browser: Browser, server: str
) -> None:
    # First in this file: no earlier page has streamed from this server yet.
    page, errors = open_page(browser, server)
    page.click("#take")
    wait(page, "(window.telerobot.state.flags & 1) !== 0")
    start = target(server)
    page.evaluate("window.__pad.axes[1] = -0.8")  # stick forward, dead-man not held
    page.wait_for_timeout(500)
    assert target(server) == start  # nothing moves without the dead-man
    page.evaluate("window.__pad.pressed.add(5)")
    deadline = time.monotonic() + 10
    while target(server) == start:  # the dead-man is held: the arm goes
        assert time.monotonic() < deadline, "the arm did not move with the dead-man held"
        time.sleep(0.1)
    page.evaluate("window.__pad.pressed.delete(5)")  # release: the arm stops
    page.wait_for_timeout(300)
    held = target(server)
    page.wait_for_timeout(600)
    assert target(server) == held
    page.click("#estop")
    wait(page, "(window.telerobot.state.flags & 4) !== 0")
    page.evaluate("window.__pad.pressed.add(5)")
    page.wait_for_timeout(600)
    assert target(server) == held  # e-stop latched: nothing moves
    assert httpx.get(server + "api/v1/safety").json()["estop"] is True
    page.evaluate("window.__pad.pressed.delete(5)")
    page.click("#reset")
    wait(page, "(window.telerobot.state.flags & 4) === 0")
    if page.locator("#release").is_visible():
        page.click("#release")
    assert errors == []
    page.close()  # one video page at a time on this machine
    # An observer page: no take-control button, and its dead-man moves nothing.
    observer, errors = open_page(browser, server, token="")
    observer.evaluate("localStorage.removeItem('telerobot.token')")
    assert observer.locator("#take").is_hidden()
    assert "observer" in (observer.locator("#role").text_content() or "")
    before = target(server)
    observer.evaluate("window.__pad.axes[1] = -0.8; window.__pad.pressed.add(5)")
    observer.wait_for_timeout(600)
    assert target(server) == before
    assert errors == []
    observer.close()


def test_page_plays_the_stereo_video_and_reports_glass_to_glass_latency(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    f0 = page.evaluate("window.telerobot.view.frames")
    page.wait_for_timeout(2000)
    assert page.evaluate("window.telerobot.view.frames") > f0 + 10  # frames advance
    # Past the start-up (first keyframe, clock sync), over the last 100 frames:
    page.wait_for_function("window.telerobot.glass.count > 150", timeout=60_000)
    p50 = float(np.median(page.evaluate("window.telerobot.glass.snapshot().slice(-100)")))
    assert 0 < p50 <= 80, p50
    assert "glass-to-glass p50" in page.locator("#latency").text_content()  # type: ignore[operator]
    assert errors == []
    page.close()


def test_anaglyph_takes_red_from_the_left_image_and_green_blue_from_the_right(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    page.uncheck("#ar")
    page.evaluate("window.telerobot.setMode('anaglyph')")
    page.evaluate("document.getElementById('video').pause()")
    result = page.evaluate(
        """() => {
        const video = document.getElementById('video');
        window.telerobot.view.redraw();
        const W = video.videoWidth / 2, H = video.videoHeight;
        const src = document.createElement('canvas'); src.width = 2 * W; src.height = H;
        const s = src.getContext('2d'); s.drawImage(video, 0, 0);
        const out = document.createElement('canvas'); out.width = W; out.height = H;
        const o = out.getContext('2d'); o.drawImage(document.getElementById('view'), 0, 0);
        const points = [];
        for (let i = 0; i < 40; i++) {
          const x = 20 + Math.floor((i * 97) % (W - 40)), y = 40 + Math.floor((i * 53) % (H - 60));
          points.push([Array.from(s.getImageData(x, y, 1, 1).data), Array.from(s.getImageData(x + W, y, 1, 1).data),
                       Array.from(o.getImageData(x, y, 1, 1).data)]);
        }
        return points;
      }"""
    )
    differ = 0
    for left, right, shown in result:
        assert abs(shown[0] - left[0]) <= 3, (left, right, shown)
        assert abs(shown[1] - right[1]) <= 3 and abs(shown[2] - right[2]) <= 3, (left, right, shown)
        differ += abs(left[0] - right[0]) > 20
    assert differ >= 3  # the check saw places where the two eyes really differ
    assert errors == []
    page.close()


def test_the_ar_ball_sits_where_the_ground_truth_camera_sees_the_gripper(
    browser: Browser, server: str
) -> None:
    page, _ = open_page(browser, server)
    page.evaluate("window.telerobot.setMode('side-by-side')")
    page.wait_for_timeout(500)
    cell = httpx.get(server + "api/v1/workcell").json()
    tool = np.array(httpx.get(server + "api/v1/robot/state").json()["position"] + [1.0])
    ball = page.evaluate("window.telerobot.ball")
    for cam, got in zip(cell["cameras"], (ball["left"], ball["right"]), strict=True):
        u, v, w = np.array(cam["P"]) @ tool
        assert np.hypot(got[0] - u / w, got[1] - v / w) <= 3.0, (got, u / w, v / w)
    # And it is drawn there, in the ball's colour, in both halves of the view.
    colours = page.evaluate(
        """([l, r]) => {
        const v = document.getElementById('view'); const c = document.createElement('canvas');
        c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
        const W = v.width / 2;
        return [Array.from(g.getImageData(Math.round(l[0]), Math.round(l[1]), 1, 1).data),
                Array.from(g.getImageData(Math.round(r[0] + W), Math.round(r[1]), 1, 1).data)];
      }""",
        [ball["left"], ball["right"]],
    )
    for rgba in colours:
        assert rgba[:3] == [0, 255, 102], (colours, ball)  # #00ff66
    page.close()


@pytest.mark.parametrize(
    "mode", ["mono", "side-by-side", "cross-eye", "anaglyph", "anaglyph-dubois"]
)
def test_screenshots_of_each_view(browser: Browser, server: str, mode: str) -> None:
    page, errors = open_page(browser, server)
    page.evaluate(f"window.telerobot.setMode('{mode}')")
    page.wait_for_timeout(700)
    SHOTS.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(SHOTS / f"view-{mode}.png"))
    assert (SHOTS / f"view-{mode}.png").stat().st_size > 10_000
    assert errors == []
    page.close()
