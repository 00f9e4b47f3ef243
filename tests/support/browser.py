"""What every browser test of the operator page shares: Debian's Chromium (launched
here, once per test session: the ``browser`` fixture in tests/conftest.py), the server's
settings for the page (video included), a page opened with a scripted gamepad (and the
emulated WebXR runtime), and waits that say what the page said when they fail."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page, Playwright

# The same Chromium flags as the browser benchmark, and its software GPU at nice 10.
from harness.chromium import ARGS, yield_software_gpu
from tests.support import TOKEN

CHROMIUM = Path("/usr/bin/chromium")  # Debian's: never a downloaded browser
ENV = {
    "TELEROBOT_VIDEO": "true",
    # 2×640×360 at 20 fps (the timecode needs 520 px of width): this 2-core machine
    # also runs the server and a software GPU.
    "TELEROBOT_VIDEO_WIDTH": "640",
    "TELEROBOT_VIDEO_HEIGHT": "360",
    "TELEROBOT_VIDEO_FPS": "20",
    # The browser shares this machine's CPU with the server here (never so in use): a
    # media worker at nice 10 waits behind the browser's software GPU, and the frames
    # reach the page late (glass-to-glass p50 19 → 63 ms with one core busy elsewhere).
    "TELEROBOT_VIDEO_NICE": "0",
    # Any free port for the priority channel: another server here may hold 8001.
    "TELEROBOT_PRIORITY_PORT": "0",
    "TELEROBOT_HOME_POSE": "qn",
    # The longest dead-man the spec allows (stop within 200 ms): a software-rendered
    # page on this loaded 2-core machine can stall its timers for 150 ms.
    "TELEROBOT_DEADMAN_TIMEOUT_S": "0.18",
}
# How long a test waits for the arm to move while it holds a key or the dead-man: a
# deadline, not a figure. With one core busy the page's software rendering can stall its
# heartbeats past the 180 ms dead-man (the longest the settings allow), each stall a halt.
DRIVE_S = 60.0
# For the tests of what the page does with no picture needed (panels, control, keys): no
# media worker on the server, no decoder in the browser, half this machine's CPU back.
NO_VIDEO = {**ENV, "TELEROBOT_VIDEO": "false"}
VIDEO_OFF = "the server responded with a status of 503"
# `make screenshots` saves them into docs/img for the README; a test run keeps the
# working tree clean and saves them in a temporary folder.
SHOTS_FOR_DOCS = os.environ.get("TELEROBOT_SCREENSHOTS")

# A gamepad the test holds: standard mapping, R1 (button 5) is the dead-man.
FAKE_GAMEPAD = """
window.__pad = { axes: [0, 0, 0, 0], pressed: new Set() };
navigator.getGamepads = () => [{
  id: "scripted", index: 0, connected: true, mapping: "standard", timestamp: performance.now(),
  axes: window.__pad.axes,
  buttons: Array.from({ length: 17 }, (_, i) => ({ pressed: window.__pad.pressed.has(i), touched: false, value: window.__pad.pressed.has(i) ? 1 : 0 })),
}];
"""


# A fake vibration actuator on the scripted gamepad records what the page asks of it.
FAKE_GAMEPAD += """
window.__rumble = [];
const __actuator = { playEffect: (type, p) => { window.__rumble.push(p.strongMagnitude); return Promise.resolve("complete"); } };
const __getGamepads = navigator.getGamepads;
navigator.getGamepads = () => __getGamepads().map((p) => Object.assign(p, { vibrationActuator: __actuator }));
"""

# WebXR in a browser with no headset: Meta's Immersive Web Emulation Runtime (iwer,
# an npm devDependency of web/) emulates a Quest 3 with its two controllers.
IWER = (
    Path(__file__).resolve().parents[2] / "web" / "node_modules" / "iwer" / "build" / "iwer.min.js"
)
XR_RUNTIME = """
window.__xr = new IWER.XRDevice(IWER.metaQuest3);
window.__xr.stereoEnabled = true;
window.__xr.installRuntime({ forceInstall: true });
"""


def chromium_or_fail() -> str:
    """Debian's Chromium's path; a clear failure where it is missing (`make test`
    installs it)."""
    if not CHROMIUM.exists():
        pytest.fail(
            "Debian's chromium is missing: `make test` installs it (apt-get install chromium)"
        )
    return str(CHROMIUM)


@contextlib.contextmanager
def chromium(playwright: Playwright, executable: str | None = None) -> Iterator[Browser]:
    """Debian's Chromium with the browser benchmark's flags (``executable``: another way
    to start it, e.g. inside a network namespace), from the session's Playwright (one
    per test process: its sync API keeps an event loop in this thread)."""
    b = playwright.chromium.launch(executable_path=executable or chromium_or_fail(), args=ARGS)
    try:
        yield b
    finally:
        b.close()


def open_page(
    browser: Browser,
    base: str,
    token: str = TOKEN,
    xr: bool = False,
    query: str = "",
    video: bool = True,
    camera_pixels: bool = True,
) -> tuple[Page, list[str]]:
    """The operator page (``query``: more of its URL's parameters, e.g. "layer=low"),
    once it plays the video (``video``) or, on a server without video (NO_VIDEO), once
    the server's state reaches it. ``camera_pixels``: its view draws every camera pixel
    (the tests read the canvas at camera coordinates), not only as many as its box shows
    (the page's default: view/stereo.ts drawingBufferSize)."""
    # The emulated headset draws at the window's size in software: a smaller window.
    page = browser.new_page(
        viewport={"width": 960, "height": 540} if xr else {"width": 1500, "height": 900}
    )
    errors: list[str] = []

    def console(msg: Any) -> None:
        # Without video the server answers the page's video requests 503 (video off),
        # which the browser logs for each one: expected there, an error anywhere else.
        if msg.type == "error" and (video or VIDEO_OFF not in msg.text):
            errors.append(msg.text)

    page.on("console", console)
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.add_init_script(FAKE_GAMEPAD)
    if camera_pixels:
        page.add_init_script("window.telerobotDrawAtCameraPixels = true;")
    if xr:
        if not IWER.exists():
            pytest.fail(
                "the WebXR emulator (iwer) is missing from web/node_modules: make test installs it"
            )
        page.add_init_script(path=str(IWER))
        page.add_init_script(XR_RUNTIME)
    params = "&".join(p for p in (f"token={token}" if token else "", query) if p)
    page.goto(base + (f"?{params}" if params else ""))
    yield_software_gpu()
    ready = "window.telerobot.view.frames > 10" if video else "window.telerobot.state"
    page.wait_for_function(f"window.telerobot && {ready}", timeout=60_000, polling=100)
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


# The view as drawn is not the video's own picture while it is stale (dimmed, "VIDEO
# STALE" over its middle: a loaded machine's late frame) or while a draw waits for the
# GPU (view/draw-pacer.ts): pixels are read from a view that is neither.
VIEW_FRESH = (
    "window.telerobot.view.staleMs === null && !(window.telerobot.view.pacer?.waiting ?? false)"
)


def read_fresh_view(page: Page, script: str, arg: Any = None, tries: int = 10) -> Any:
    """``script`` (a JS function of ``arg``) run in the page at a moment the view shows
    fresh video: right after a new frame is drawn and while the view is neither stale
    nor waiting, judged and read in the same turn of the page's event loop. (Judged from
    here, each check a round trip: on a busy machine the low layer's page dimmed its
    view again within each round trip, ten reads in a row.) Up to ``tries`` rounds of
    20 s each."""
    for _ in range(tries):
        fresh, got = page.evaluate(
            f"""async (arg) => {{
  const view = () => window.telerobot.view;
  const deadline = performance.now() + 20000;
  const after = view().frames + 1;
  while (performance.now() < deadline) {{
    await new Promise((r) => setTimeout(r, 5));
    if (view().frames > after && {VIEW_FRESH}) return [true, ({script})(arg)];
  }}
  return [false, null];
}}""",
            arg,
        )
        if fresh:
            return got
    raise AssertionError(f"the view was stale at each of {tries} reads")


def target(server: str) -> list[float]:
    return httpx.get(server + "api/v1/robot/state").json()["target_joints"]


def tool_position(server: str) -> np.ndarray:
    return np.array(httpx.get(server + "api/v1/robot/state").json()["position"])


def page_said(page: Page, what: str | Callable[[], str]) -> Callable[[], str]:
    """For ``until``'s ``what``: what was waited for, and what the page said."""

    def said() -> str:
        messages = page.locator("#messages").inner_text()
        flags = page.evaluate("window.telerobot.state && window.telerobot.state.flags")
        return (
            f"never: {what if isinstance(what, str) else what()}; flags {flags}; "
            f"page messages:\n{messages}"
        )

    return said


def xr_frames_pass(page: Page, n: int = 2) -> None:
    """Wait until the XR session has drawn ``n`` more frames: the page has read the
    controllers' state as it is now (a busy page draws 1–9 XR frames/s here)."""
    n0 = page.evaluate("window.telerobot.view.xrFrames")
    wait(page, f"window.telerobot.view.xrFrames >= {n0 + n}")


def assert_ball_on_the_tool(
    page: Page, server: str, within_px: float = 3.0
) -> dict[str, list[float]]:
    """The AR ball is drawn where the ground-truth cameras see the tool point; returns
    the ball's pixels in each eye."""
    page.evaluate("window.telerobot.setMode('side-by-side')")
    page.wait_for_timeout(500)
    cell = httpx.get(server + "api/v1/workcell").json()
    tool = np.array(httpx.get(server + "api/v1/robot/state").json()["position"] + [1.0])
    ball: dict[str, list[float]] = page.evaluate("window.telerobot.ball")
    for cam, got in zip(cell["cameras"], (ball["left"], ball["right"]), strict=True):
        u, v, w = np.array(cam["P"]) @ tool
        assert np.hypot(got[0] - u / w, got[1] - v / w) <= within_px, (got, u / w, v / w)
    return ball


def take_control(page: Page) -> None:
    page.click("#take")
    wait(page, "(window.telerobot.state.flags & 1) !== 0")


def drop_video_peer(page: Page, server: str) -> str:
    """The server closes this page's video peer for real (its secret proves it is the
    page's), as a crashed or restarted media worker would: no new frame arrives.
    Returns the closed peer's id."""
    peer = page.evaluate(
        "({ id: window.telerobot.video.peerId, secret: window.telerobot.video.peerSecret })"
    )
    r = httpx.delete(
        server + f"api/v1/webrtc/{peer['id']}",
        headers={"X-Peer-Secret": peer["secret"], "X-Telerobot-Client": "test"},
    )
    assert r.status_code < 300, r.text
    return str(peer["id"])
