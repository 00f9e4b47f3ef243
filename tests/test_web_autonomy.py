"""Supervising a policy from the operator page, in a real browser against the real
server, with a policy client driving over the priority channel: the header says
AUTONOMOUS; T (and the Take over button) takes over, the policy's next command is
refused and said to it, the arm does not jump, the page drives from where the arm is;
H (and Hand back) gives control back; P pauses and resumes; holding the dead-man takes
over and letting go hands back; the e-stop pauses it."""

from __future__ import annotations

import time

import httpx
import pytest
from playwright.sync_api import Browser, Page

from harness.policy_stub import PolicyClient
from tests.support import TOKEN, until
from tests.support.browser import (
    DRIVE_S,
    ENV,
    NO_VIDEO,
    open_page,
    page_said,
    target,
    wait,
    xr_frames_pass,
)
from tests.support.servers import serving

pytestmark = pytest.mark.browser
SERVER_ENV = NO_VIDEO
STEP_LIMIT_M = 0.025  # the server's per-increment limit (0.25 m/s × 0.1 s)
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def mode(server: str) -> str:
    return str(httpx.get(server + "api/v1/autonomy").json()["mode"])


def badge(page: Page) -> str:
    return page.locator("#autonomy").inner_text() if page.is_visible("#autonomy") else ""


def press(page: Page, key: str) -> None:
    page.click("#view")  # the page, not a control, has the focus
    page.keyboard.press(key)


def test_the_page_takes_over_from_a_policy_and_hands_back(browser: Browser, server: str) -> None:
    with PolicyClient(server, TOKEN) as policy:
        page, errors = open_page(browser, server, video=False)
        wait(page, "document.getElementById('autonomy').textContent.startsWith('AUTONOMOUS')")
        assert "test-policy" in badge(page)
        assert page.locator("#take").inner_text() == "Take over (T)"

        # T: the operator takes over; the policy's next command is refused and said.
        took = time.monotonic()
        press(page, "t")
        until(lambda: mode(server) == "correcting", timeout=10, what=page_said(page, "T takes"))
        wait(page, "document.getElementById('autonomy').textContent.startsWith('CORRECTING')")
        until(lambda: policy.refused_since(took), timeout=5, what=lambda: "the policy refused")
        assert "is correcting: your command was not applied" in policy.refused_since(took)[0].text
        held = target(server)
        time.sleep(0.3)
        assert target(server) == held  # stopped where it was: nothing of the policy's applied
        # The page drives from there.
        page.keyboard.down("Space")
        page.keyboard.down("KeyW")
        until(lambda: target(server) != held, timeout=DRIVE_S, what=page_said(page, "W drives"))
        page.keyboard.up("KeyW")
        page.keyboard.up("Space")

        # H: back to the policy, which drives on from where the arm is.
        wait(page, "!document.getElementById('hand-back').hidden")
        press(page, "h")
        until(lambda: mode(server) == "autonomous", timeout=10, what=page_said(page, "H hands"))
        back = time.monotonic()
        until(lambda: policy.applied_since(back), timeout=5, what=lambda: "it drives again")

        # The buttons do the same.
        page.click("#take")
        until(lambda: mode(server) == "correcting", timeout=10, what=page_said(page, "button"))
        wait(page, "!document.getElementById('hand-back').hidden")
        page.click("#hand-back")
        until(lambda: mode(server) == "autonomous", timeout=10, what=page_said(page, "hand back"))

        # P pauses (the policy refused, told it is paused), P again resumes.
        press(page, "p")
        until(lambda: mode(server) == "paused", timeout=10, what=page_said(page, "P pauses"))
        paused = time.monotonic()
        until(lambda: policy.refused_since(paused), timeout=5)
        assert "autonomy is paused (paused by" in policy.refused_since(paused)[-1].text
        press(page, "p")
        until(lambda: mode(server) == "autonomous", timeout=10, what=page_said(page, "resumes"))

        # Holding the dead-man takes over; letting go hands back.
        page.click("#view")
        page.keyboard.down("Space")
        until(lambda: mode(server) == "correcting", timeout=10, what=page_said(page, "dead-man"))
        page.keyboard.up("Space")
        until(lambda: mode(server) == "autonomous", timeout=10, what=page_said(page, "let go"))

        # The e-stop during autonomy pauses it.
        press(page, "Escape")
        until(lambda: mode(server) == "paused", timeout=10, what=page_said(page, "e-stop"))
        wait(page, "document.getElementById('autonomy').textContent.includes('e-stop')")
        state = httpx.get(server + "api/v1/autonomy").json()
        assert state["interventions"] == 3, state  # T, the button, the dead-man
        assert policy.largest_step_m() < STEP_LIMIT_M  # no jump at any handover
        assert not errors, errors


def test_the_xr_grip_takes_over_from_a_policy_and_letting_go_hands_back(
    browser: Browser,
) -> None:
    """In the emulated headset (iwer): gripping the right controller while the policy
    drives takes over at once; the grip's motion drives; let go, control goes back."""
    with serving(ENV) as server, PolicyClient(server, TOKEN) as policy:
        page, errors = open_page(browser, server, xr=True)
        wait(page, "document.getElementById('autonomy').textContent.startsWith('AUTONOMOUS')")
        page.click("#xr")
        wait(page, "window.telerobot.view.xrPresenting")
        # In the headset, where the header is not seen, a line above the picture says it.
        wait(page, "window.telerobot.view.xrBadgeVisible")
        hand = "window.__xr.controllers.right"
        # iwer marks every space as emulated; a tracked controller is not (the page
        # ignores a hand whose position is only estimated).
        page.evaluate(
            f"() => {{ const s = {hand}.inputSource.gripSpace;"
            "s[Object.getOwnPropertySymbols(s).find((k) => k.description === '@iwer/xr-space')]"
            ".emulated = false; }"
        )
        took = time.monotonic()
        page.evaluate(f"{hand}.updateButtonValue('squeeze', 1)")
        until(lambda: mode(server) == "correcting", timeout=10, what=page_said(page, "grip"))
        until(lambda: policy.refused_since(took), timeout=5, what=lambda: "the policy refused")
        held = target(server)
        for _ in range(20):
            page.evaluate(f"{hand}.position.z -= 0.004")
            page.wait_for_timeout(50)
        until(lambda: target(server) != held, timeout=DRIVE_S, what=page_said(page, "drives"))
        page.evaluate(f"{hand}.updateButtonValue('squeeze', 0)")
        xr_frames_pass(page)
        until(lambda: mode(server) == "autonomous", timeout=10, what=page_said(page, "let go"))
        assert policy.largest_step_m() < STEP_LIMIT_M
        assert not errors, errors


def _estop_reset(server: str) -> None:
    """The e-stop reset if an earlier test left it latched (REST: take, reset, release)."""
    if not httpx.get(server + "api/v1/safety").json()["estop"]:
        return
    with httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=10) as rest:
        me = {
            "X-Client-Id": rest.post("lease", json={"name": "tidy", "force": True}).json()[
                "client_id"
            ]
        }
        rest.post("safety/reset", headers=me).raise_for_status()
        rest.delete("lease", headers=me)


def test_an_estop_during_a_takeover_then_a_reset_from_the_page_leaves_the_policy_paused(
    browser: Browser, server: str
) -> None:
    """Issue 49's path 1, as the page does it: the dead-man takes over, Escape, let go
    (the page hands back with the e-stop latched), reset from the page: the arm does not
    move and the page says the policy waits for P."""
    _estop_reset(server)
    with PolicyClient(server, TOKEN) as policy:
        page, errors = open_page(browser, server, video=False)
        wait(page, "document.getElementById('autonomy').textContent.startsWith('AUTONOMOUS')")
        page.click("#view")
        page.keyboard.down("Space")
        until(lambda: mode(server) == "correcting", timeout=10, what=page_said(page, "dead-man"))
        page.keyboard.press("Escape")
        until(lambda: httpx.get(server + "api/v1/safety").json()["estop"], timeout=10)
        page.keyboard.up("Space")  # the page hands back after HAND_BACK_MS
        until(lambda: mode(server) == "paused", timeout=10, what=page_said(page, "let go"))
        wait(page, "!document.getElementById('reset').hidden")
        page.click("#reset")
        until(lambda: not httpx.get(server + "api/v1/safety").json()["estop"], timeout=10)
        reset = time.monotonic()
        held = target(server)
        until(lambda: policy.refused_since(reset), timeout=5, what=lambda: "the policy refused")
        time.sleep(0.5)
        assert target(server) == held and mode(server) == "paused"
        assert not policy.applied_since(reset)
        wait(
            page,
            "document.getElementById('autonomy').textContent.includes('press P to let it drive')",
        )
        assert not errors, errors
