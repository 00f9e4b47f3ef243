"""Recording from the operator page in a real browser against the real
server on the simulation, video included: the operator records and marks an episode,
an observer sees the REC indicator advance, the file reads back with its labelled
episode, and the review page plays it."""

from __future__ import annotations

import re
import time
from pathlib import Path

import httpx
import pytest
from playwright.sync_api import Browser, Page

from telerobot.server.recording.reader import read
from tests.support import TOKEN, until
from tests.support.browser import (
    DRIVE_S,
    open_page,
    page_said,
    take_control,
    tool_position,
    wait,
)

pytestmark = pytest.mark.browser

NAME = "web-test-recording"
TASK = "push the block 5 cm"
NOTES = "driven with Space+W"


def indicator(page: Page) -> tuple[int, float]:
    """The header's indicator as (elapsed s, size MB): ● REC mm:ss · x.xx MB."""
    text = page.locator("#rec-indicator").inner_text()
    m = re.fullmatch(r"● REC (\d+):(\d\d) · ([\d.]+) MB", text.strip())
    assert m, f"the indicator says {text!r}"
    return int(m[1]) * 60 + int(m[2]), float(m[3])


def test_operator_records_an_episode_observer_sees_rec_review_plays_it(
    browser: Browser, server: str, tmp_path: Path
) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    page, errors = open_page(browser, server)
    wait(page, "window.telerobot.client.operator && window.telerobot.recording.polls > 0")
    assert page.locator("#rec-indicator").inner_text() == "not recording"
    wait(page, "!document.getElementById('rec-start').hidden")
    page.fill("#rec-name", NAME)
    page.click("#rec-start")
    wait(page, "window.telerobot.recording.view.recording === true", 15_000)
    assert NAME in (page.locator("#rec-summary").inner_text())
    assert page.locator("#rec-stop").is_visible()
    assert page.locator("#rec-indicator.rec-on").is_visible()

    # An observer sees the indicator, elapsed and size advancing, and no controls.
    observer, observer_errors = open_page(browser, server, token="")
    observer.evaluate("localStorage.removeItem('telerobot.token')")
    wait(observer, "document.getElementById('rec-indicator').textContent.startsWith('● REC')")
    assert observer.locator("#rec-indicator.rec-on").is_visible()
    elapsed0, size0 = indicator(observer)
    deadline = time.monotonic() + 30
    while True:
        elapsed, size = indicator(observer)
        if elapsed >= elapsed0 + 2 and size > size0:
            break
        assert time.monotonic() < deadline, f"the indicator stays at {elapsed} s, {size} MB"
        observer.wait_for_timeout(250)
    assert observer.locator("#rec-start").is_hidden()
    assert observer.locator("#rec-stop").is_hidden()
    assert observer.locator("#rec-episode-start").is_hidden()
    assert observer_errors == []
    observer.close()  # one video page at a time on this machine, beyond here

    # An episode: start with a task name, drive a little, end it as a success.
    take_control(page)
    page.fill("#rec-task", TASK)
    page.click("#rec-episode-start")
    wait(page, "window.telerobot.recording.view.episodes === 1")
    assert TASK in page.locator("#rec-episode").inner_text()
    assert page.locator("#rec-success").is_enabled()
    assert page.locator("#rec-episode-start").is_disabled()
    page.evaluate("document.activeElement && document.activeElement.blur()")
    page.keyboard.press("Digit1")  # the base frame
    x0 = tool_position(server)[0]
    page.keyboard.down("KeyW")
    page.keyboard.down("Space")
    until(
        lambda: tool_position(server)[0] >= x0 + 0.005,
        timeout=DRIVE_S,
        what=page_said(page, "the arm moves with Space+W"),
    )
    page.keyboard.up("Space")
    page.keyboard.up("KeyW")
    page.fill("#rec-notes", NOTES)
    page.click("#rec-success")
    wait(page, "document.getElementById('rec-episode').textContent.includes('✓')")

    # Stop: the review link names the file.
    page.click("#rec-stop")
    wait(page, "window.telerobot.recording.view.recording === false", 30_000)
    wait(page, "!document.getElementById('rec-review').hidden")
    assert page.locator("#rec-indicator").inner_text() == "not recording"
    href = page.locator("#rec-review").get_attribute("href") or ""
    file = page.evaluate("window.telerobot.recording.last")
    assert file.endswith(f"-{NAME}.mcap")
    assert href == f"review.html?id={file}"
    assert errors == []
    page.close()

    # Listed with one labelled episode.
    listing = httpx.get(server + "api/v1/recordings").json()
    (entry,) = [r for r in listing if r["file"] == file]
    assert entry["complete"] and not entry["active"]
    assert entry["name"] == NAME
    (ep,) = entry["episodes"]
    assert (ep["task"], ep["success"], ep["notes"]) == (TASK, True, NOTES)
    assert ep["ended"] is not None

    # The file reads back: the episode's start and end, its label; commands and force.
    path = tmp_path / file
    with httpx.stream("GET", server + f"api/v1/recordings/{file}/download", headers=auth) as r:
        r.raise_for_status()
        with path.open("wb") as f:
            for chunk in r.iter_bytes():
                f.write(chunk)
    episodes = [m for _, _, m in read(path, topics=["/episodes"])]
    assert [e["event"] for e in episodes] == ["start", "end"]
    assert all(e["task"] == TASK and e["episode"] == 0 for e in episodes)
    assert (episodes[1]["success"], episodes[1]["notes"]) == (True, NOTES)
    counts: dict[str, int] = {}
    for topic, _, _ in read(path, topics=["/commands", "/force", "/video/stereo"]):
        counts[topic] = counts.get(topic, 0) + 1
    assert counts.get("/commands", 0) > 0 and counts.get("/force", 0) > 100, counts
    assert counts.get("/video/stereo", 0) > 10, counts

    # The review page (the link's address) plays it: video, force plot, command log.
    review = browser.new_page(viewport={"width": 1500, "height": 900})
    review_errors: list[str] = []
    review.on("console", lambda m: review_errors.append(m.text) if m.type == "error" else None)
    review.on("pageerror", lambda e: review_errors.append(str(e)))
    review.goto(server + href)
    review.wait_for_function("document.body.dataset.reviewReady === '1'", timeout=60_000)
    loaded = review.evaluate(
        "({forces: review.forces, commands: review.commands, videoStart: review.videoStart,"
        " duration: review.duration})"
    )
    assert loaded["forces"] > 10 and loaded["commands"] > 0, loaded
    assert loaded["videoStart"] is not None and loaded["duration"] > 2, loaded
    assert review.locator("#review-commands li").count() == loaded["commands"]
    review.wait_for_function("review.video.readyState >= 2", timeout=30_000)
    review.click("#review-play")
    review.wait_for_function(
        "!review.video.paused && review.video.currentTime > 1", timeout=30_000, polling=100
    )
    # The force plot has the recorded forces drawn (coloured pixels beyond the cursor).
    coloured = review.evaluate(
        """() => {
          const c = document.getElementById('review-force');
          const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          let n = 0;
          for (let i = 0; i < d.length; i += 4) if (d[i + 3] > 0 && !(d[i] === d[i + 1] && d[i + 1] === d[i + 2])) n++;
          return n;
        }"""
    )
    assert coloured > 100
    # The ball and the ghost at the recorded predicted pose (the commanded joints) in
    # both eyes, beside the actual tool: the arm follows its target within a few px.
    overlay = review.evaluate("review.overlay")
    for eye in (0, 1):
        predicted, actual = overlay["predicted"][eye], overlay["actual"][eye]
        assert predicted and actual, overlay
        assert abs(predicted[0] - actual[0]) < 15 and abs(predicted[1] - actual[1]) < 15, overlay
    # rectified cameras: the same row in both eyes
    assert abs(overlay["predicted"][0][1] - overlay["predicted"][1][1]) < 3, overlay
    assert review.locator("#review-time").inner_text().startswith("0:0")
    assert review_errors == []
    review.close()
