"""Browser tests of the hand as a master and the ghost arm: in the
emulated WebXR runtime (iwer) in hand mode, a pinch is the clutch and the hand's motion
moves the arm; the whole predicted arm is drawn over both eyes, and can be switched off."""

from __future__ import annotations

import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from tests.support import until
from tests.support.browser import (
    DRIVE_S,
    open_page,
    page_said,
    read_fresh_view,
    take_control,
    target,
    tool_position,
    wait,
    xr_frames_pass,
)

pytestmark = pytest.mark.browser

HAND = "window.__xr.hands.right"

# Magenta pixels (the ghost's joints) of the #view canvas: how many in each half (each
# eye, side by side and in XR), and for each given canvas point whether one lies within
# 4 px of it.
MAGENTA = """(points) => {
  const v = document.getElementById('view'); const c = document.createElement('canvas');
  c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  const magenta = (x, y) => {
    if (x < 0 || y < 0 || x >= c.width || y >= c.height) return false;
    const i = 4 * (y * c.width + x);
    return d[i] > 200 && d[i + 1] < 90 && d[i + 2] > 200;
  };
  const halves = [0, 0];
  for (let y = 0; y < c.height; y++) for (let x = 0; x < c.width; x++)
    if (magenta(x, y)) halves[x < c.width / 2 ? 0 : 1]++;
  const near = points.map(([px, py]) => {
    for (let dy = -4; dy <= 4; dy++) for (let dx = -4; dx <= 4; dx++)
      if (magenta(Math.round(px) + dx, Math.round(py) + dy)) return true;
    return false;
  });
  return { halves, near };
}"""

# The ghost's joints in canvas pixels of the side-by-side view: each camera's pixel, the
# right eye's half to the right (moved by the alignment shift), less the cropped rows.
GHOST_POINTS = """() => {
  const t = window.telerobot, at = t.view.layout;
  const W = at.eyeWidth, crop = at.cropTop, shift = { x: at.shift[0], y: at.shift[1] };
  const pts = [];
  t.ghost.pixels.forEach((chain, e) => chain.forEach((p) => {
    if (!p) return;
    const x = p[0] + e * (W + shift.x), y = p[1] - crop + e * shift.y;
    if (x >= e * W + 6 && x < (e + 1) * W - 6 && y >= 6 && y < at.outHeight - 6) pts.push([x, y, e]);
  }));
  return pts;
}"""


def _frames_pass(page: Page, n: int = 2) -> None:
    """Wait until ``n`` more video frames were drawn, with the overlay as it is now (the
    video keeps playing: a paused one is a stalled one to the page, which reconnects)."""
    n0 = page.evaluate("window.telerobot.view.frames")
    wait(page, f"window.telerobot.view.frames >= {n0 + n}", timeout=30_000)


def test_the_ghost_arm_is_drawn_along_the_predicted_chain_in_both_eyes_and_switches_off(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    wait(page, "window.telerobot.ghost.pixels[0].length === 8")
    assert page.locator("#ghost").is_checked()  # on by default
    page.evaluate("window.telerobot.setMode('side-by-side')")
    _frames_pass(page)
    points = page.evaluate(GHOST_POINTS)
    assert sum(1 for p in points if p[2] == 0) >= 4 and sum(1 for p in points if p[2] == 1) >= 4
    on = read_fresh_view(page, MAGENTA, [p[:2] for p in points])
    for (x, y, eye), found in zip(points, on["near"], strict=True):
        assert found, f"no ghost joint at ({x:.0f}, {y:.0f}) in eye {eye}: {on}"
    assert on["halves"][0] > 20 and on["halves"][1] > 20, on

    page.uncheck("#ghost")
    assert page.evaluate("localStorage.getItem('telerobot.ghost')") == "off"
    _frames_pass(page)
    off = read_fresh_view(page, MAGENTA, [p[:2] for p in points])
    assert not any(off["near"]), off
    assert sum(off["halves"]) < 0.05 * sum(on["halves"]), (on, off)

    page.check("#ghost")
    _frames_pass(page)
    again = read_fresh_view(page, MAGENTA, [p[:2] for p in points])
    assert all(again["near"]), again
    assert errors == []
    page.close()


def test_a_pinching_hand_in_the_emulated_runtime_moves_the_arm(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, xr=True)
    page.evaluate("window.__xr.primaryInputMode = 'hand'")  # no controllers: two hands
    take_control(page)
    page.click("#xr")
    wait(page, "window.telerobot.view.xrPresenting && window.telerobot.view.xrFrames > 5")
    sources = page.evaluate(
        "window.__xr.activeSession.inputSources.length === 2"
        " && Array.from(window.__xr.activeSession.inputSources).every((s) => !!s.hand)"
    )
    assert sources, "the session has no tracked hands (hand-tracking not granted?)"

    # The ghost (whole predicted arm) is drawn in both eyes in XR too.
    xr_frames_pass(page)
    eyes = page.evaluate(MAGENTA, [])
    assert eyes["halves"][0] > 10 and eyes["halves"][1] > 10, eyes

    # An open hand moves nothing.
    start, p0 = target(server), tool_position(server)
    ghost0 = page.evaluate("window.telerobot.ghost.pixels[0].at(-1)")
    for _ in range(10):
        page.evaluate(f"{HAND}.position.x += 0.004")
        page.wait_for_timeout(50)
    xr_frames_pass(page)
    assert target(server) == start

    # Pinch, then move the hand 8 cm to the right: the gripper follows, to base −y
    # (XR x right → base −y), scaled by the speed (0.5).
    page.evaluate(f"{HAND}.updatePinchValue(1)")
    xr_frames_pass(page)  # the clutch anchors in the first frame that sees the pinch
    for _ in range(20):
        page.evaluate(f"{HAND}.position.x += 0.004")
        page.wait_for_timeout(50)
    until(
        lambda: (tool_position(server) - p0)[1] <= -0.02,
        timeout=DRIVE_S,
        what=page_said(
            page,
            lambda: (
                f"the gripper follows the hand 2 cm to the right: moved {tool_position(server) - p0}"
            ),
        ),
    )
    assert target(server) != start
    page.evaluate(f"{HAND}.updatePinchValue(0)")
    xr_frames_pass(page)
    page.wait_for_timeout(500)  # the commands already sent reach their targets
    moved = tool_position(server) - p0
    assert moved[1] < 0, moved.tolist()
    assert abs(moved[0]) < 0.3 * -moved[1] and abs(moved[2]) < 0.3 * -moved[1], moved.tolist()
    # The ghost moved with the prediction.
    ghost1 = page.evaluate("window.telerobot.ghost.pixels[0].at(-1)")
    assert np.hypot(ghost1[0] - ghost0[0], ghost1[1] - ghost0[1]) > 3, (ghost0, ghost1)

    # Released: the hand moves nothing.
    held = target(server)
    for _ in range(10):
        page.evaluate(f"{HAND}.position.x += 0.004")
        page.wait_for_timeout(50)
    xr_frames_pass(page)
    assert target(server) == held
    assert errors == []
    page.close()
