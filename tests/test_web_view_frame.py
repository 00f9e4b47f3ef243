"""The view frame in a real browser against the simulation: the keys
move the gripper as the left camera's image shows it, and the active frame's axis marker
is drawn at the gripper in both eyes."""

from __future__ import annotations

import time

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from tests.support import until
from tests.support.browser import (
    open_page,
    page_said,
    read_fresh_view,
    take_control,
    tool_position,
    wait,
)

pytestmark = pytest.mark.browser

STEP_M = 0.02  # how far each key is held for


def left_camera(server: str) -> np.ndarray:
    return np.array(httpx.get(server + "api/v1/calibration").json()["cameras"][0]["P"])


def seen(P: np.ndarray, p: np.ndarray) -> tuple[float, float, float]:
    """``p`` in the camera's image (u, v pixels) and its depth along the optical axis (m)."""
    u, v, w = P @ np.append(p, 1.0)
    return u / w, v / w, w / np.linalg.norm(P[2, :3])


def at_rest(server: str, timeout: float = 10) -> np.ndarray:
    """The tool's position once the arm has stopped (not moving, its target unchanged
    between two polls)."""
    last: list[float] = []
    deadline = time.monotonic() + timeout
    while True:
        state = httpx.get(server + "api/v1/robot/state").json()
        if state["status"] != "MOVING" and state["target_joints"] == last:
            return np.array(state["position"])
        last = state["target_joints"]
        assert time.monotonic() < deadline, "the arm never came to rest"
        time.sleep(0.1)


def hold(page: Page, server: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Hold Space + ``key`` until the tool has moved STEP_M; where it was and is, at rest."""
    before = at_rest(server)
    # A released dead-man keeps the lease only for a grace period (lease_grace_s).
    if not page.evaluate("(window.telerobot.state.flags & 1) !== 0"):
        take_control(page)
    page.keyboard.down(key)
    page.keyboard.down("Space")
    try:
        until(
            lambda: np.linalg.norm(tool_position(server) - before) >= STEP_M,
            what=page_said(page, f"Space+{key} moves the gripper"),
            # A deadline, not a figure: with one core busy the page's software rendering
            # can stall its heartbeats past the 180 ms dead-man, each stall a halt.
            timeout=60,
        )
    finally:
        page.keyboard.up("Space")
        page.keyboard.up(key)
    return before, at_rest(server)


def test_view_frame_w_moves_the_projected_gripper_up_the_image_away_from_the_camera(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    assert page.evaluate("window.telerobot.loop.frame") == "view"  # the default
    assert page.locator("#frame").input_value() == "view"
    take_control(page)
    P = left_camera(server)

    before, after = hold(page, server, "KeyW")
    (u0, v0, z0), (u1, v1, z1) = seen(P, before), seen(P, after)
    assert z1 - z0 > 0.5 * STEP_M, (z0, z1)  # away from the camera
    assert v1 - v0 < -2, (v0, v1)  # up the image
    assert abs(u1 - u0) < abs(v1 - v0), (u0, u1, v0, v1)  # more than sideways

    before, after = hold(page, server, "KeyA")
    (u0, v0, z0), (u1, v1, z1) = seen(P, before), seen(P, after)
    assert u1 - u0 < -5, (u0, u1)  # left in the image
    assert abs(v1 - v0) < 0.5 * abs(u1 - u0), (v0, v1)
    assert abs(z1 - z0) < 0.3 * STEP_M, (z0, z1)  # at the same depth

    before, after = hold(page, server, "KeyR")
    (u0, v0, z0), (u1, v1, z1) = seen(P, before), seen(P, after)
    assert v1 - v0 < -5, (v0, v1)  # up the image
    assert abs(u1 - u0) < 0.5 * abs(v1 - v0), (u0, u1)

    # 1 picks the base frame again: W is base +x there.
    page.keyboard.press("Digit1")
    assert page.locator("#frame").input_value() == "base"
    before, after = hold(page, server, "KeyW")
    d = after - before
    assert d[0] > 0.8 * np.linalg.norm(d), d
    page.keyboard.press("Digit4")
    assert page.locator("#frame").input_value() == "view"
    if page.locator("#release").is_visible():
        page.click("#release")
    assert errors == []
    page.close()


# Per eye: pixels of each axis colour (x red, y green, z blue) within `r` pixels of the
# marker's origin on the #view canvas (side by side; each eye's top `crop` rows not shown).
MARKER_PIXELS = """([origins, r]) => {
  const v = document.getElementById('view'), video = document.getElementById('video');
  const c = document.createElement('canvas'); c.width = v.width; c.height = v.height;
  const g = c.getContext('2d'); g.drawImage(v, 0, 0);
  const W = v.width / 2, crop = video.videoHeight - v.height;
  return origins.map(([u, vv], eye) => {
    const counts = [0, 0, 0];
    const x0 = Math.max(0, Math.round(u - r)), y0 = Math.max(0, Math.round(vv - crop - r));
    const w = Math.min(W, Math.round(u + r)) - x0, h = Math.min(v.height, Math.round(vv - crop + r)) - y0;
    if (w <= 0 || h <= 0) return counts;
    const d = g.getImageData(eye * W + x0, y0, w, h).data;
    for (let i = 0; i < d.length; i += 4) {
      const [R, G, B] = [d[i], d[i + 1], d[i + 2]];
      if (R > 200 && G < 100 && B < 100) counts[0]++;            // #ff3030
      else if (G > 170 && R < 120 && B < 90) counts[1]++;        // #30e030 (not the ball's #00ff66)
      else if (B > 200 && R < 110 && G > 90 && G < 170) counts[2]++; // #3080ff
    }
    return counts;
  });
}"""


def test_the_view_frame_axis_marker_is_drawn_at_the_gripper_in_both_eyes(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    page.evaluate("window.telerobot.setMode('side-by-side')")
    cell = httpx.get(server + "api/v1/calibration").json()
    tool = np.append(at_rest(server), 1.0)
    origins = []
    for cam in cell["cameras"][:2]:
        u, v, w = np.array(cam["P"]) @ tool
        origins.append([u / w, v / w])
    # The marker's origin is where the cameras see the gripper (the prediction has
    # snapped to the arm at rest).
    wait(
        page, "window.telerobot.axes.pixels[0] !== null && window.telerobot.axes.pixels[1] !== null"
    )
    drawn = page.evaluate("window.telerobot.axes.pixels")
    for eye in (0, 1):
        got = drawn[eye][0]
        assert np.hypot(got[0] - origins[eye][0], got[1] - origins[eye][1]) <= 3, (got, origins)

    def counts() -> list[list[int]]:
        frames = page.evaluate("window.telerobot.view.frames")
        wait(page, f"window.telerobot.view.frames > {frames + 2}")  # drawn since
        return read_fresh_view(page, MARKER_PIXELS, [origins, 45])

    shown = counts()
    page.uncheck("#ar")  # the marker goes with the AR ball
    hidden = counts()
    page.check("#ar")
    for eye in (0, 1):
        for axis in range(3):
            assert shown[eye][axis] >= hidden[eye][axis] + 8, (eye, axis, shown, hidden)
    assert errors == []
    page.close()
