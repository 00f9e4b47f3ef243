"""Issue 55: a correction taken over from a policy at the page holds on a loaded machine.

One core is kept busy (Debian's stress-ng) for the whole test, and the page's main thread
is made to stand still for ``STALL_S`` while the dead-man is held, as a loaded 2-core
machine's did (6.1 s measured with a policy supervised): the dead-man stops the arm
(the server's halt), the page keeps its lease and its correction, the keys still held
drive again once the page runs again, and H hands back. Before the fix the page's
worker stopped its heartbeats for good once the main thread had been silent for 1 s, so
the lease lapsed after the server's grace (the page said "no heartbeat for 2889 ms") and
the policy paused, the keys latched. The stall is made on purpose (as test_web_deadman
stalls the worker), so this holds on a quiet machine as on a busy one.
"""

from __future__ import annotations

import contextlib
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator

import httpx
import pytest
from playwright.sync_api import Browser, Page

from harness.policy_stub import PolicyClient
from tests.support import TOKEN, until
from tests.support.browser import (
    DRIVE_S,
    NO_VIDEO,
    open_page,
    page_said,
    tool_position,
    wait,
)

pytestmark = pytest.mark.browser
SERVER_ENV = NO_VIDEO  # the page's stall is the point here, not the picture

# The page's main thread stands still this long (past the worker's PAGE_SILENCE_MS of
# 1 s, under its PAGE_HUNG_MS of 10 s): longer than any lease the server keeps for a
# silent holder (its 0.18 s dead-man, then 2 s of grace, 4 s at most).
STALL_S = 8.0
HOLD_S = 10.0  # the dead-man held at least this long, the lease kept throughout
MOVED_M = 0.003  # the tool moved along x with W held (the base frame)
CONTROL_S = 30.0  # a take or a hand-back answered within this, on a loaded machine


@contextlib.contextmanager
def busy_core() -> Iterator[None]:
    """One core kept busy meanwhile: Debian's stress-ng, else a Python loop."""
    stress = shutil.which("stress-ng")
    cmd = [stress, "--cpu", "1", "--quiet"] if stress else [sys.executable, "-c", "while 1: pass"]
    proc = subprocess.Popen(cmd)
    try:
        yield
    finally:
        proc.terminate()
        proc.wait(10)


def safety(server: str) -> dict[str, object]:
    return dict(httpx.get(server + "api/v1/safety", timeout=30).json())


def autonomy(server: str) -> dict[str, object]:
    return dict(httpx.get(server + "api/v1/autonomy", timeout=30).json())


def stall_the_page(page: Page, seconds: float) -> None:
    """Keep the page's main thread busy: no input read, no command, no check-in with
    its worker, as a page waiting for a loaded machine's CPU (or its software GPU)."""
    page.evaluate(
        f"() => {{ const t = performance.now(); while (performance.now() - t < {seconds * 1000}) {{}} }}"
    )


def test_a_correction_keeps_its_lease_through_a_stalled_page_and_h_hands_back(
    browser: Browser, server: str
) -> None:
    with busy_core(), PolicyClient(server, TOKEN) as policy:
        page, errors = open_page(browser, server, video=False)
        wait(
            page, "document.getElementById('autonomy').textContent.startsWith('AUTONOMOUS')", 30_000
        )
        page.click("#view")  # the page, not a control, has the focus
        page.keyboard.press("Digit1")  # the base frame: W drives along base x

        # The dead-man takes over from the policy; W drives from where the arm is.
        took = time.monotonic()
        page.keyboard.down("Space")
        until(
            lambda: autonomy(server)["mode"] == "correcting",
            timeout=CONTROL_S,
            what=page_said(page, "the dead-man takes over"),
        )
        interventions = autonomy(server)["interventions"]
        x0 = tool_position(server)[0]
        page.keyboard.down("KeyW")
        until(
            lambda: tool_position(server)[0] > x0 + MOVED_M,
            timeout=DRIVE_S,
            what=page_said(page, "W drives while correcting"),
        )

        # The page stands still: the dead-man stops the arm; the lease stays the page's.
        halts = safety(server)["deadman_halts"]
        assert isinstance(halts, int)
        stall_the_page(page, STALL_S)
        until(
            lambda: safety(server)["deadman_halts"] > halts,  # type: ignore[operator]
            timeout=CONTROL_S,
            what="the dead-man stopped the arm of the page standing still",
        )
        state = autonomy(server)
        assert state["mode"] == "correcting", state  # the lease did not lapse meanwhile
        x1 = tool_position(server)[0]
        until(
            lambda: tool_position(server)[0] > x1 + MOVED_M,
            timeout=DRIVE_S,
            what=page_said(page, "the keys still held drive again"),
        )
        time.sleep(max(0.0, HOLD_S - (time.monotonic() - took)))
        state = autonomy(server)
        assert state["mode"] == "correcting", state
        assert state["interventions"] == interventions, state  # never lost and taken again
        assert policy.told_since(took, "paused") is None, policy.autonomy
        assert page.evaluate("(window.telerobot.state.flags & 1) !== 0")  # YOU_HAVE_CONTROL

        # H, the dead-man still held: back to the policy, which drives again.
        page.keyboard.press("KeyH")
        until(
            lambda: autonomy(server)["mode"] == "autonomous",
            timeout=CONTROL_S,
            what=page_said(page, "H hands back"),
        )
        back = time.monotonic()
        page.keyboard.up("KeyW")
        page.keyboard.up("Space")
        until(lambda: policy.applied_since(back), timeout=CONTROL_S, what="the policy drives again")
        assert "handed back by" in str(autonomy(server)["cause"])
        assert not errors, errors
