"""The review page as a new user meets it, in Debian's Chromium
against the real server on the simulation, video included. A short recording made over
REST while the operator page holds control (its lease taken over the page's WebSocket),
with an episode and an e-stop in it, reviews with: the episode (task, ✗, notes) as a
span and the e-stop as a tick on the timeline strip, both in the event list, a click
there seeking to it; each command's sender named once ("ws 127.0.0.1:…", not
"ws ws 127.0.0.1:…"); the picture without the cameras' timecode stripe, as the live
page shows it; no empty box; and the episode numbered as the API numbers it (from 0)
there, in the Recording panel and in the Tasks panel."""

from __future__ import annotations

import json
import re
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser

from tests.support import TOKEN, until
from tests.support.browser import open_page, take_control, wait

pytestmark = pytest.mark.browser

NAME = "web-test-review"
TASK = "touch the block"
NOTES = "e-stopped half way"
# view/stereo.ts's TIMECODE_ROWS: the rows of each eye the live page does not show.
TIMECODE_ROWS = 28
AUTH = {"Authorization": f"Bearer {TOKEN}"}

# Every element shown in the header and the page's main part that shows nothing: no
# text, no child, a list with no option (a canvas, a video, a control is never empty).
EMPTY_BOXES = """() => [...document.querySelectorAll('header > *, #review > *')]
  .filter((e) => e.getClientRects().length > 0)
  .filter((e) => e.tagName === 'SELECT' ? e.options.length === 0
    : !['CANVAS', 'VIDEO', 'INPUT', 'BUTTON'].includes(e.tagName)
      && e.textContent.trim() === '' && e.children.length === 0)
  .map((e) => e.id || e.tagName)"""
# A sender named twice over: "ws ws 127.0.0.1:…", "rest rest …".
TWICE = re.compile(r"\b(ws|priority|rest|task|server) \1\b")


def test_review_shows_episodes_and_safety_events_and_numbers_episodes_as_the_api(
    browser: Browser, server: str
) -> None:
    http = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)

    def active() -> dict[str, Any]:
        return dict(http.get("recordings/active").json())

    # The operator page, playing (the media worker is up: the recording gets video).
    page, errors = open_page(browser, server)
    wait(page, "window.telerobot.client.operator && window.telerobot.recording.polls > 0")
    r = http.post("recordings", json={"name": NAME})
    assert r.status_code == 200, r.text
    take_control(page)  # a command from the page's WebSocket: "browser on …" (ws)
    r = http.post("recordings/active/episodes", json={"task": TASK})
    assert r.status_code == 200, r.text
    number = r.json()["episode"]
    assert number == 0  # the API's numbering: from 0
    # The Recording panel says the same number.
    said = json.dumps(f"episode {number} “{TASK}”")
    wait(page, f"document.getElementById('rec-episode').textContent.startsWith({said})")
    started = active()["elapsed_s"]
    until(lambda: active()["elapsed_s"] > started + 1, timeout=30, what="a second recorded")
    r = http.post("safety/estop")  # anyone may press it
    assert r.status_code == 200 and r.json()["estop"], r.text
    pressed = active()["elapsed_s"]
    until(lambda: active()["elapsed_s"] > pressed + 1, timeout=30, what="a second after it")
    r = http.post("recordings/active/episodes/end", json={"success": False, "notes": NOTES})
    assert r.status_code == 200, r.text
    until(
        lambda: (a := active())["elapsed_s"] > 4 and a["bytes"] > 50_000,
        timeout=60,
        what=lambda: f"a few seconds of video recorded: {active()}",
    )
    entry = http.post("recordings/active/stop").json()
    file = entry["file"]
    (listed,) = entry["episodes"]
    assert listed["episode"] == number and listed["success"] is False

    # The Tasks panel offers it under the same number.
    page.click("#task-refresh")
    listed_js = "[...document.querySelectorAll('#task-recording option')].map((o) => o.value)"
    wait(page, f"{listed_js}.includes({json.dumps(file)})")
    page.select_option("#task-recording", file)
    options = page.locator("#task-episode option").all_inner_texts()
    assert options and options[0].startswith(f"{number}: {TASK}"), options
    assert errors == []
    page.close()  # one video page at a time on this machine

    review = browser.new_page(viewport={"width": 1500, "height": 900})
    review_errors: list[str] = []
    review.on("console", lambda m: review_errors.append(m.text) if m.type == "error" else None)
    review.on("pageerror", lambda e: review_errors.append(str(e)))
    review.goto(server + f"review.html?id={file}")
    review.wait_for_function("document.body.dataset.reviewReady === '1'", timeout=60_000)
    loaded: dict[str, Any] = review.evaluate(
        "({episodes: review.episodes, safety: review.safety, duration: review.duration,"
        " videoStart: review.videoStart})"
    )
    # The episode, as labelled, and the e-stop inside it.
    (episode,) = loaded["episodes"]
    assert (episode["episode"], episode["task"], episode["success"], episode["notes"]) == (
        number,
        TASK,
        False,
        NOTES,
    )
    estops = [m for m in loaded["safety"] if m["kind"] == "estop"]
    assert len(estops) == 1, loaded["safety"]
    estop_at = estops[0]["time"]
    assert episode["start"] < estop_at < episode["end"], loaded
    assert any(m["kind"] == "lease" for m in loaded["safety"]), loaded["safety"]
    # …in the event list, in words,
    events = review.locator("#review-events li").all_inner_texts()
    assert any(f"episode {number} “{TASK}” ✗ — {NOTES}" in e for e in events), events
    assert any(e.split(" ", 1)[1].startswith("e-stop: e-stop pressed") for e in events), events
    # …and on the strip under the force plot: a span, and a tick inside it.
    strip = review.evaluate(
        """() => {
          const ep = document.querySelector('#review-marks .episode');
          const tick = document.querySelector('#review-marks .safety.estop');
          const box = (e) => { const r = e.getBoundingClientRect(); return [r.left, r.right, r.width]; };
          return { episode: ep && box(ep), text: ep && ep.textContent, estop: tick && box(tick) };
        }"""
    )
    assert strip["episode"] and strip["estop"], strip
    assert strip["episode"][2] > 20, strip  # a span, not a line
    mid = (strip["estop"][0] + strip["estop"][1]) / 2
    assert strip["episode"][0] < mid < strip["episode"][1], strip
    assert f"episode {number}" in strip["text"], strip

    # Each command's sender once; the page's WebSocket among them.
    commands = review.locator("#review-commands li").all_inner_texts()
    assert commands, "no command listed"
    assert not [c for c in commands if TWICE.search(c)], commands
    # (The page names itself, "browser on <platform>" by default: web/src/ui/operator-name.ts.)
    assert any(re.search(r" browser on [^()]* \(ws\) ", c) for c in commands), commands

    # The picture without the timecode stripe, as the live page shows it.
    review.wait_for_function("review.video.readyState >= 2", timeout=30_000)
    frame = review.evaluate(
        "({crop: review.frame.crop, height: document.getElementById('review-view').height,"
        " videoHeight: review.video.videoHeight})"
    )
    assert frame["crop"] == TIMECODE_ROWS, frame
    assert frame["height"] == frame["videoHeight"] - TIMECODE_ROWS, frame

    # A click on the e-stop's line goes there (or to the video's first frame, if later).
    review.locator("#review-events li.estop").click()
    there = max(estop_at, loaded["videoStart"])
    review.wait_for_function(
        f"Math.abs(Number(document.getElementById('review-seek').value) - {there}) < 0.3",
        timeout=10_000,
    )

    assert review.evaluate(EMPTY_BOXES) == []
    assert review_errors == []
    review.close()
