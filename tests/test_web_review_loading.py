"""The review page loading a 2-minute recording (issue 55), in Debian's Chromium against
the real server: it shows a loading indicator with progress from the first moment, asks
for the video at once and shows its first picture before the timeline has arrived, then
loads the timeline in pieces, the plots and lists growing as each comes and the cursor
working meanwhile, until it is the whole timeline.

The order is the test's, not the machine's: the page's timeline requests are held in the
browser (Playwright's routing) and let through one at a time, so what the page shows
while a piece is missing is seen on any machine, however slow; nothing is timed.

The recording is built (harness/recordings.py, ``build``): 120 s of forces at 1 kHz,
states at 50 Hz, a command every 0.25 s (and a refused one between), an episode early
and one late, and 20 fps video (256×64, each frame its number in blocks) — what a
2-minute recording holds, at a small picture."""

from __future__ import annotations

import re
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.sync_api import Browser, Page, Route

from harness.recordings import Episode, build
from tests.support import TOKEN
from tests.support.browser import NO_VIDEO
from tests.support.servers import serving

pytestmark = pytest.mark.browser

AUTH = {"Authorization": f"Bearer {TOKEN}"}
TIMELINE = re.compile(r"/api/v1/recordings/[^/]+/timeline")
VIDEO = re.compile(r"/api/v1/recordings/[^/]+/video\.mp4")
DURATION = 120.0


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("review-loading")
    return build(
        folder / "20260101-000000-two-minutes.mcap",
        duration=DURATION,
        episodes=[Episode(2.0, 8.0, "pick the block"), Episode(60.0, 100.0, "place the block")],
    ).path


@pytest.fixture(scope="module")
def server(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A server whose recordings folder holds the recording (nothing read of it yet). No
    camera: the review's video is the recording's."""
    state = tmp_path_factory.mktemp("state")
    (state / "recordings").mkdir()
    shutil.copy(recording, state / "recordings" / recording.name)
    with serving(NO_VIDEO, "--state-dir", str(state)) as base:
        yield base


class HeldTimeline:
    """The page's timeline requests, held until let through one at a time; its video's,
    held until let through."""

    def __init__(self, page: Page) -> None:
        self.held: list[Route] = []
        self.video: list[Route] = []
        self.asked: list[str] = []  # every request the page made, in order (their paths)
        self.open = {"timeline": False, "video": False}
        page.on("request", lambda r: self.asked.append(r.url.split("/api/v1/")[-1]))
        page.route(TIMELINE, lambda route: self._hold(route, "timeline", self.held))
        page.route(VIDEO, lambda route: self._hold(route, "video", self.video))

    def _hold(self, route: Route, what: str, held: list[Route]) -> None:
        if self.open[what]:
            route.continue_()
        else:
            held.append(route)

    def let_the_video_through(self, page: Page) -> None:
        _wait(page, lambda: len(self.video) > 0, "the page's video request")
        self.open["video"] = True
        for route in self.video:
            route.continue_()
        self.video.clear()

    def let_one_through(self, page: Page) -> str:
        _wait(page, lambda: len(self.held) > 0, "the page's next timeline request")
        route = self.held.pop(0)
        route.continue_()
        return route.request.url

    def let_all_through(self) -> None:
        self.open["timeline"] = True
        for route in self.held:
            route.continue_()
        self.held.clear()


def _wait(page: Page, ok: Any, what: str, timeout_s: float = 120.0) -> None:
    """Waits for a condition of the test's own (Playwright's events dispatched meanwhile)."""
    for _ in range(int(timeout_s * 10)):
        if ok():
            return
        page.wait_for_timeout(100)
    raise AssertionError(f"never: {what}")


def shown(page: Page) -> dict[str, Any]:
    result: dict[str, Any] = page.evaluate(
        """() => {
          const box = document.getElementById('review-loading');
          const bar = document.getElementById('review-loading-bar');
          const r = window.review ?? {};
          return {
            indicator: !!box && !box.hidden && box.getClientRects().length > 0,
            words: box ? box.textContent.trim() : '',
            progress: bar ? bar.value / bar.max : null,
            pictures: r.pictures ? r.pictures.drawn : 0,
            loading: r.loading ?? null,
            ready: document.body.dataset.reviewReady === '1',
            forces: r.forces ?? 0,
            commands: document.querySelectorAll('#review-commands li').length,
            episodes: (r.episodes ?? []).length,
            seekMax: Number(document.getElementById('review-seek').max),
          };
        }"""
    )
    return result


def test_the_review_shows_progress_and_its_first_picture_before_the_timeline(
    browser: Browser, server: str, recording: Path
) -> None:
    with httpx.Client(base_url=server + "api/v1/recordings/", headers=AUTH, timeout=120) as http:
        whole = http.get(f"{recording.name}/timeline", params={"max_points": 4000}).json()
    page = browser.new_page(viewport={"width": 1500, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    timeline = HeldTimeline(page)
    page.goto(server + f"review.html?id={recording.name}")

    # From the first moment, before any of the timeline or the video has come: the
    # indicator says what is loading, with its progress at nothing yet.
    _wait(page, lambda: len(timeline.held) > 0, "the page's first timeline request")
    before = shown(page)
    assert before["indicator"], before
    assert "timeline" in before["words"] and "video" in before["words"], before
    assert before["progress"] == 0, before
    # The video asked for at once, first, not after the timeline…
    asked = [a for a in timeline.asked if "/video.mp4" in a or "/timeline" in a]
    assert asked[0].endswith("/video.mp4"), timeline.asked
    # …and its first picture drawn while no piece of the timeline has come.
    timeline.let_the_video_through(page)
    page.wait_for_function("window.review && window.review.pictures.drawn > 0", timeout=120_000)
    with_picture = shown(page)
    assert with_picture["loading"]["loadedTo"] == 0 and not with_picture["ready"], with_picture
    assert with_picture["indicator"] and "video ready" in with_picture["words"], with_picture
    assert 0 < with_picture["progress"] < 1, with_picture

    # The first piece: small (the first seconds), its plots and lists shown, the rest
    # still to come (the next piece held), the indicator saying how far.
    first_url = timeline.let_one_through(page)
    assert "start_s=0" in first_url and "end_s=10" in first_url, first_url
    page.wait_for_function("window.review.loading.loadedTo > 0", timeout=60_000)
    _wait(page, lambda: len(timeline.held) > 0, "the page's second timeline request")
    part = shown(page)
    assert part["indicator"] and not part["ready"], part
    assert "timeline 0:10.0 of 2:00.0" in part["words"], part
    assert 0 < part["progress"] < 1, part
    assert 0 < part["forces"] < len(whole["topics"]["/force"]), part
    assert 0 < part["commands"] < len(whole["topics"]["/commands"]), part
    assert part["episodes"] == 1 and part["seekMax"] == pytest.approx(whole["duration"]), part
    # The cursor works meanwhile: a seek moves the video there.
    page.evaluate(
        "() => { const s = document.getElementById('review-seek'); s.value = '5';"
        " s.dispatchEvent(new Event('input')); }"
    )
    page.wait_for_function(
        f"Math.abs(review.video.currentTime - (5 - {whole['video_start']})) < 0.2",
        timeout=30_000,
    )

    # The second piece: the lists grow, still not the whole.
    timeline.let_one_through(page)
    page.wait_for_function("window.review.loading.loadedTo > 10", timeout=60_000)
    grown = shown(page)
    assert part["forces"] < grown["forces"] < len(whole["topics"]["/force"]), grown
    assert part["commands"] < grown["commands"], grown
    assert not grown["ready"] and grown["indicator"], grown

    # The rest: the whole timeline, the indicator gone.
    timeline.let_all_through()
    page.wait_for_function("document.body.dataset.reviewReady === '1'", timeout=120_000)
    done = shown(page)
    assert not done["indicator"], done
    assert done["forces"] == len(whole["topics"]["/force"]), done
    assert done["commands"] == len(whole["topics"]["/commands"]), done
    assert done["episodes"] == 2, done
    pieces = [a for a in timeline.asked if "/timeline" in a]
    assert len(pieces) == 3, pieces  # a 2-minute recording: three pieces
    assert errors == []
    page.close()
