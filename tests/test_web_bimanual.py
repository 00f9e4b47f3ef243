"""The operator page on a server with two arms (two simulated SO-101s facing each other
across the table): both drawn, each its AR ball and ghost where its own mount puts it;
the left XR controller drives the left arm and the right the right, each with its own
grip; the keys drive the arm their key selects; the gamepad's left side the left arm.
Debian's Chromium against `telerobot serve` (no video: what is checked is the page's
state and the arms' motion, read back through GET /api/v1/robot/state?arm=…)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from tests.support import until
from tests.support.browser import (
    DRIVE_S,
    NO_VIDEO,
    open_page,
    page_said,
    take_control,
    wait,
    xr_frames_pass,
)

pytestmark = pytest.mark.browser

SERVER_ENV = {**NO_VIDEO, "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim"}
ARMS = ("left", "right")


def state(server: str, arm: str) -> dict[str, Any]:
    r = httpx.get(server + f"api/v1/robot/state?arm={arm}")
    assert r.status_code == 200, r.text
    data: dict[str, Any] = r.json()
    return data


def position(server: str, arm: str) -> np.ndarray:
    return np.array(state(server, arm)["position"])


def target(server: str, arm: str) -> list[float]:
    return state(server, arm)["target_joints"]


def release(page: Page) -> None:
    """Give control back (as the Release button does; in XR the headset covers it)."""
    page.evaluate("window.telerobot.loop.release()")
    wait(page, "(window.telerobot.state.flags & 1) === 0")


def drives_only(server: str, page: Page, arm: str, what: str, move: Callable[[], None]) -> None:
    """``move`` (the input that drives ``arm``, held) moves it 5 mm (in its own base
    frame) while the other arm stays where it was told to be."""
    other = next(a for a in ARMS if a != arm)
    p0, held = position(server, arm), target(server, other)
    move()
    until(
        lambda: np.linalg.norm(position(server, arm) - p0) > 0.005,
        timeout=DRIVE_S,
        what=page_said(page, f"{what} moves the {arm} arm"),
    )
    assert target(server, other) == held, f"{what} moved the {other} arm too"


def test_both_arms_are_drawn_each_ball_and_ghost_where_its_mount_puts_it(
    browser: Browser, server: str
) -> None:
    arms = httpx.get(server + "api/v1/robot/arms").json()
    assert [a["name"] for a in arms] == list(ARMS)
    page, errors = open_page(browser, server, video=False)
    wait(page, "window.telerobot.balls.length === 2 && window.telerobot.balls.every((b) => b.left)")
    cameras = httpx.get(server + "api/v1/workcell").json()["cameras"]
    balls = page.evaluate("window.telerobot.balls")
    assert len(balls) == 2
    for arm, ball in zip(arms, balls, strict=True):
        # The tool point of each arm's own base frame, placed in the scene by its mount,
        # as the ground-truth cameras see it.
        tool = np.array(arm["mount"]) @ np.array([*position(server, arm["name"]), 1.0])
        for cam, got in zip(cameras, (ball["left"], ball["right"]), strict=True):
            u, v, w = np.array(cam["P"]) @ tool
            assert np.hypot(got[0] - u / w, got[1] - v / w) <= 3.0, (arm["name"], got, u / w)
    assert np.hypot(*np.subtract(balls[0]["left"], balls[1]["left"])) > 20  # two places
    # Both rings in the view's program, each shown; each arm's ghost in both eyes (base,
    # the five joints that carry the tool, the tool).
    shown = page.evaluate("[window.telerobot.view.ballSlots, window.telerobot.view.ballsShown]")
    assert shown == [2, [1, 1, 0, 0]], shown
    chains = page.evaluate("window.telerobot.arms.map((a) => a.ghost.pixels.map((c) => c.length))")
    assert chains == [[7, 7], [7, 7]], chains
    # A chip per arm in the header; the keys' arm (the left, at first) highlighted.
    assert page.locator("#arms .arm-chip").count() == 2
    assert page.locator("#arms .arm-chip.selected").inner_text().startswith("left")
    wait(page, "window.telerobot.arms.map((a) => a.ghost.highlighted).join() === 'true,false'")
    assert errors == []
    page.close()


def test_the_arm_select_key_makes_the_keys_drive_the_right_arm(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, video=False)
    take_control(page)
    page.keyboard.press("Digit1")  # the base frame
    page.keyboard.press("BracketRight")  # the keys drive the right arm
    wait(page, "window.telerobot.loop.selected === 1")
    assert page.locator("#arms .arm-chip.selected").inner_text().startswith("right")
    # (redrawn at the next animation frame)
    wait(page, "window.telerobot.arms.map((a) => a.ghost.highlighted).join() === 'false,true'")

    def keys() -> None:
        page.keyboard.down("KeyW")
        page.keyboard.down("Space")

    drives_only(server, page, "right", "Space + W after ]", keys)
    page.keyboard.up("Space")
    page.keyboard.up("KeyW")
    release(page)
    assert errors == []
    page.close()


def test_the_gamepads_left_side_drives_the_left_arm(browser: Browser, server: str) -> None:
    page, errors = open_page(browser, server, video=False)
    take_control(page)
    # L1 (button 4), the left arm's dead-man, and the left stick forward.
    drives_only(
        server,
        page,
        "left",
        "L1 + the left stick",
        lambda: page.evaluate("window.__pad.axes[1] = -0.8; window.__pad.pressed.add(4)"),
    )
    page.evaluate("window.__pad.axes[1] = 0; window.__pad.pressed.delete(4)")
    release(page)
    assert errors == []
    page.close()


def test_each_xr_controller_drives_its_own_arm_with_its_own_grip(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, xr=True, video=False)
    take_control(page)
    page.click("#xr")
    wait(page, "window.telerobot.view.xrPresenting && window.telerobot.view.xrFrames > 5")
    for hand in ARMS:
        # iwer marks every space as emulated (estimated); a tracked controller is not,
        # and the page ignores one whose position is only estimated.
        page.evaluate(
            f"(() => {{ const s = window.__xr.controllers.{hand}.inputSource.gripSpace;"
            "s[Object.getOwnPropertySymbols(s).find((k) => k.description === '@iwer/xr-space')]"
            ".emulated = false; })()"
        )
    for hand in ARMS:
        controller = f"window.__xr.controllers.{hand}"

        def grip_and_move(controller: str = controller) -> None:
            page.evaluate(f"{controller}.updateButtonValue('squeeze', 1)")
            xr_frames_pass(page)  # the clutch anchors in the first frame that sees the grip
            for _ in range(20):  # 8 cm forward (−z in XR): into the picture
                page.evaluate(f"{controller}.position.z -= 0.004")
                page.wait_for_timeout(50)

        drives_only(server, page, hand, f"the {hand} controller's grip", grip_and_move)
        page.evaluate(f"{controller}.updateButtonValue('squeeze', 0)")
        xr_frames_pass(page)
        page.wait_for_timeout(300)  # the commands already sent reach their targets
    # Let go: neither hand moves anything.
    held = [target(server, a) for a in ARMS]
    for _ in range(5):
        page.evaluate(
            "window.__xr.controllers.left.position.z -= 0.004;"
            " window.__xr.controllers.right.position.z -= 0.004"
        )
        page.wait_for_timeout(50)
    xr_frames_pass(page)
    assert [target(server, a) for a in ARMS] == held
    release(page)
    assert errors == []
    page.close()
