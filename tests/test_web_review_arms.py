"""The review page plays a two-arm recording back (docs/recording.md), in Debian's
Chromium against a real two-arm server with video: a recording made while both
simulated SO-101s move shows each arm's ghost and ring where that arm was (through its
own mount: the two in different places of the picture, each ring at its ghost's tool
once at rest), each arm's forces and joints, and each command's arm."""

from __future__ import annotations

import time
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser

from telerobot.client import Telerobot
from tests.support import TOKEN, until
from tests.support.browser import ENV

pytestmark = pytest.mark.browser

SERVER_ENV = {**ENV, "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim"}
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ARMS = ("left", "right")
JOG = {"left": [0.0, 0.0, 0.002], "right": [0.0, 0.002, 0.0]}


def test_the_review_plays_both_arms_back(browser: Browser, server: str) -> None:
    with httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=60) as http:
        until(lambda: http.get("video").json()["worker_alive"], 60, "the media worker", poll=0.1)
        assert http.post("recordings", json={"name": "two arms review"}).status_code == 200
        with Telerobot(server, TOKEN, name="teacher") as robot:
            for _ in range(25):
                for arm in ARMS:
                    robot.move_cartesian(JOG[arm], relative=True, wait=False, arm=arm)
                time.sleep(0.03)
            until(
                lambda: all(robot.arm(a).state()["status"] == "READY" for a in ARMS),
                10,
                "both arms at rest",
                poll=0.05,
            )
        until(lambda: http.get("recordings/active").json()["elapsed_s"] > 2.5, 30, poll=0.1)
        file = http.post("recordings/active/stop").json()["file"]

    page = browser.new_page(viewport={"width": 1500, "height": 900})
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(server + f"review.html?id={file}")
    page.wait_for_function("document.body.dataset.reviewReady === '1'", timeout=60_000)
    page.wait_for_function("review.video.readyState >= 2", timeout=30_000)
    # The end of the recording: both arms at rest where they were jogged to.
    page.evaluate("review.video.currentTime = review.video.duration")
    page.wait_for_function(
        "['left', 'right'].every((a) => review.overlay.arms[a]?.predicted[0]"
        " && review.overlay.arms[a]?.actual[0])",
        timeout=30_000,
    )
    shown: dict[str, Any] = page.evaluate(
        "({arms: review.arms, overlay: review.overlay.arms,"
        " joints: document.getElementById('review-joints').textContent,"
        " commands: [...document.querySelectorAll('#review-commands li')].map((l) => l.textContent)})"
    )
    assert [a["name"] for a in shown["arms"]] == list(ARMS)
    assert all(a["states"] > 20 and a["forces"] > 20 for a in shown["arms"]), shown["arms"]
    tools = {}
    for arm in ARMS:
        for eye in (0, 1):
            predicted = shown["overlay"][arm]["predicted"][eye]
            actual = shown["overlay"][arm]["actual"][eye]
            # At rest: the ring (where it was) at the ghost's tool (where it was sent).
            assert abs(predicted[0] - actual[0]) < 4 and abs(predicted[1] - actual[1]) < 4, arm
        tools[arm] = shown["overlay"][arm]["actual"][0]
    # Two arms, each through its own mount: not drawn one over the other.
    apart = abs(tools["left"][0] - tools["right"][0]) + abs(tools["left"][1] - tools["right"][1])
    assert apart > 20, tools
    lines = shown["joints"].splitlines()
    assert [line.split(":")[0] for line in lines] == list(ARMS), lines
    assert "shoulder_pan" in lines[0] and "gripper" in lines[1], lines
    jogs = [c for c in shown["commands"] if "cartesian_increment" in c]
    assert any(c.endswith("cartesian_increment left") for c in jogs), jogs
    assert any(c.endswith("cartesian_increment right") for c in jogs), jogs
    assert errors == []
    page.close()
