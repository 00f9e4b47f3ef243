"""The operator page's header and panels in a real browser:
one state model drives the header (E-STOP latched, DISCONNECTED), the help overlay,
the labels (the model's joint names, the speed's value, force numbers, orientation), the Home button
and the message log in view."""

from __future__ import annotations

import re

import httpx
import numpy as np
import pinocchio as pin
import pytest
from playwright.sync_api import Browser, Page

from tests.support import TOKEN, until
from tests.support.browser import (
    NO_VIDEO,
    open_page,
    page_said,
    take_control,
    target,
    wait,
)
from tests.support.servers import serving

pytestmark = pytest.mark.browser
# Nothing here needs the picture: the page without video, the machine's CPU for the rest.
SERVER_ENV = NO_VIDEO

BADGE = "document.getElementById('status').textContent"
ESTOP_LATCHED = "document.getElementById('estop').classList.contains('latched')"


def release(page: Page) -> None:
    if page.locator("#release").is_visible():
        page.click("#release")


def reset_estop(page: Page) -> None:
    page.click("#reset")
    wait(page, "(window.telerobot.state.flags & 4) === 0")


def test_header_shows_the_estop_latched_and_clears_after_reset(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, video=False)
    take_control(page)
    wait(page, "document.getElementById('control-owner').textContent === 'you have control'")
    wait(page, f"{BADGE} === 'READY' && !{ESTOP_LATCHED}")
    assert page.locator("#estop").text_content() == "E-STOP"
    page.click("#estop")
    wait(page, f"{BADGE} === 'E-STOP' && {ESTOP_LATCHED}")
    assert page.locator("#estop").text_content() == "E-STOP LATCHED"
    assert "ESTOP" in (page.locator("#status").get_attribute("class") or "")
    assert page.locator("#reset").is_visible()
    assert "E-STOP latched" in page.locator("#banner").inner_text()
    assert httpx.get(server + "api/v1/safety").json()["estop"] is True
    reset_estop(page)
    wait(page, f"{BADGE} === 'READY' && !{ESTOP_LATCHED}")
    assert page.locator("#estop").text_content() == "E-STOP"
    assert page.locator("#reset").is_hidden()
    wait(page, "document.getElementById('banner').hidden")
    release(page)
    assert errors == []
    page.close()


def test_header_says_disconnected_when_the_server_goes_away(browser: Browser) -> None:
    # A server of its own, to kill (the module's server serves the other tests).
    with serving(NO_VIDEO) as base:
        page, _ = open_page(browser, base, video=False)
        take_control(page)
        wait(page, "document.getElementById('control-owner').textContent === 'you have control'")
    # the server is gone (terminated as its block ended)
    wait(page, f"{BADGE} === 'DISCONNECTED'", timeout=20_000)
    header = page.locator("header").inner_text()
    assert "you have control" not in header
    assert "control: unknown (disconnected)" in header
    assert page.locator("#release").is_hidden()
    assert page.locator("#home").is_hidden()
    assert page.locator("#estop").is_visible()  # the e-stop is always there
    assert "Disconnected" in page.locator("#banner").inner_text()
    page.close()


def test_question_mark_opens_the_help_escape_closes_it_then_estops(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, video=False)
    take_control(page)
    assert page.locator("#help").is_hidden()
    page.keyboard.press("?")
    wait(page, "!document.getElementById('help').hidden")
    help_text = page.locator("#help").inner_text()
    for needed in ("Space", "W / S", "Q / E", "Escape", "E-STOP", "Alt + arrows", "R1", "pinch"):
        assert needed in help_text, needed
    assert (page.locator("#help").bounding_box() or {}).get("width", 0) > 0
    page.keyboard.press("Escape")  # closes the help, and only that (not the e-stop too)
    wait(page, "document.getElementById('help').hidden")
    page.wait_for_timeout(300)
    assert httpx.get(server + "api/v1/safety").json()["estop"] is False
    page.keyboard.press("Escape")  # nothing open: the e-stop key
    wait(page, "(window.telerobot.state.flags & 4) !== 0")
    assert httpx.get(server + "api/v1/safety").json()["estop"] is True
    reset_estop(page)
    # The header's "?" button toggles it too; `?` again closes it.
    page.click("#help-button")
    wait(page, "!document.getElementById('help').hidden")
    page.keyboard.press("?")
    wait(page, "document.getElementById('help').hidden")
    release(page)
    assert errors == []
    page.close()


def test_labels_joints_speed_forces_and_orientation(browser: Browser, server: str) -> None:
    page, errors = open_page(browser, server, video=False)
    names = httpx.get(server + "api/v1/robot/model").json()["joint_names"]
    wait(page, f"document.querySelectorAll('#joints th').length === {len(names)}")
    assert page.locator("#joints th").all_inner_texts() == names  # joint1 … joint6
    state = httpx.get(server + "api/v1/robot/state").json()  # the arm is at rest here
    shown = [float(t.rstrip("°")) for t in page.locator("#joints td").all_inner_texts()]
    assert np.allclose(shown, state["joints_deg"], atol=0.06), (shown, state["joints_deg"])
    # The tool's orientation: the rotation vector of the server's rotation matrix
    # (pinocchio's log3), then roll/pitch/yaw.
    text = page.locator("#orientation").inner_text()
    num = r"(-?\d+\.\d)"
    m = re.fullmatch(
        rf"rotation vector {num}, {num}, {num}° · roll {num}° pitch {num}° yaw {num}°", text
    )
    assert m, text
    rotvec = np.degrees(pin.log3(np.array(state["rotation"])))
    assert np.allclose([float(g) for g in m.groups()[:3]], rotvec, atol=0.06), (text, rotvec)
    # The speed's value, and it follows the slider.
    assert page.locator("#speed-value").inner_text() == "0.50"
    page.fill("#speed", "0.8")
    wait(page, "document.getElementById('speed-value').textContent === '0.80'")
    page.fill("#speed", "0.5")
    wait(page, "document.getElementById('speed-value').textContent === '0.50'")
    # The force bars: each axis named with its number and unit; the limit shown.
    rows = page.locator("#force-bars .force-row")
    assert rows.count() == 6
    for i, (axis, unit) in enumerate(
        [("Fx", "N"), ("Fy", "N"), ("Fz", "N"), ("Tx", "N·m"), ("Ty", "N·m"), ("Tz", "N·m")]
    ):
        assert rows.nth(i).locator(".axis").inner_text() == axis
        value = rows.nth(i).locator(".value").inner_text()
        assert re.fullmatch(rf"-?\d+\.\d\d {unit}", value), value
    limit = httpx.get(server + "api/v1/safety").json()["force_limit_n"]
    assert page.locator("#force-limit").inner_text() == f"limit {limit:.0f} N"
    assert errors == []
    page.close()


def test_home_button_moves_the_arm_to_the_home_pose(browser: Browser, server: str) -> None:
    model = httpx.get(server + "api/v1/robot/model").json()
    home = model["named_poses"][model["home_pose"]]
    page, errors = open_page(browser, server, video=False)
    wait(page, "window.telerobot.state !== null")
    assert page.locator("#home").is_hidden()  # only with control
    take_control(page)
    wait(page, "!document.getElementById('home').hidden")
    # Jog away: a joint increment as this page's client (it holds the lease).
    client_id = page.evaluate("window.telerobot.client.clientId")
    r = httpx.post(
        server + "api/v1/robot/move",
        json={"space": "joint", "mode": "incremental", "joints": [0.05, -0.04, 0.04, 0, 0.05, 0]},
        headers={"Authorization": f"Bearer {TOKEN}", "X-Client-Id": client_id},
        timeout=60,
    )
    assert r.status_code == 200, r.text
    assert not np.allclose(target(server), home, atol=1e-3)
    page.click("#home")  # first click: asks to confirm, moves nothing
    wait(page, "document.getElementById('home').textContent === 'Confirm: move home'")
    page.wait_for_timeout(300)
    assert not np.allclose(target(server), home, atol=1e-3)
    page.click("#home")
    until(
        lambda: np.allclose(target(server), home, atol=1e-9),
        what=page_said(page, lambda: f"target {target(server)} reaches the home pose {home}"),
        timeout=30,
    )
    wait(page, "document.getElementById('messages').textContent.includes('home: at the home pose')",
         timeout=30_000)  # fmt: skip
    wait(page, "!document.getElementById('home').disabled")
    joints = httpx.get(server + "api/v1/robot/state").json()["joints"]
    assert np.allclose(joints, home, atol=1e-3), joints  # it got there
    release(page)
    assert errors == []
    page.close()


def test_the_message_log_is_in_view_and_shows_a_new_message(browser: Browser, server: str) -> None:
    page, errors = open_page(browser, server, video=False)
    log = page.locator("#messages")

    def in_viewport(box: dict[str, float] | None) -> bool:
        return (
            box is not None
            and box["width"] > 0
            and box["height"] > 0
            and box["x"] >= 0
            and box["y"] >= 0
            and box["x"] + box["width"] <= 1500
            and box["y"] + box["height"] <= 900
        )

    assert in_viewport(log.bounding_box()), log.bounding_box()
    before = log.inner_text()
    page.click("#estop")  # the server says so in an event
    wait(page, f"document.getElementById('messages').innerText !== {before!r}")
    newest = log.locator("li").first
    assert newest.inner_text()
    assert in_viewport(newest.bounding_box()), newest.bounding_box()
    assert in_viewport(log.bounding_box())
    take_control(page)
    reset_estop(page)
    release(page)
    assert errors == []
    page.close()
