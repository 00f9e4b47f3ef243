"""How long the review page takes to show a recording (issue 55): a real server's
recording, opened in Debian's headless Chromium on a server that has read nothing of it
yet (no kept timeline, no kept MP4).

    python -m bench.review_load [--json] [--recording FILE | --seconds 120] [--busy]
        [--keep FILE] [--runs 1]

- ``first_progress_s``: from the page's navigation to its loading indicator shown
  (null: the page shows none);
- ``first_picture_s``: to the first frame of the video drawn on the page's canvas;
- ``first_plots_s``: to the timeline's first seconds on the page (the page before issue
  55: its whole timeline);
- ``timeline_complete_s``: to the whole timeline on the page (its plots and lists);
- ``requests_s``: on another fresh server, each read the page makes timed alone, one
  after the other, with the token (the server's job for it, and sending it): the whole
  timeline, its first piece (0–10 s), the MP4.

The recording: ``--recording FILE`` (an MCAP a server made; copied into the server's
folder), or one of ``--seconds`` made now by a real server with video on at its default
size (2×1280×720, 30 fps), the simulated arm jogged every 0.1 s over REST (commands,
states, 1 kHz forces, video, as an operator's session records them); ``--keep FILE``
saves it for the next run. ``--busy``: one core kept busy (``stress-ng --cpu 1``)
while the page loads. ``--token``: the page opened with the operator token (its reads
outside the tokenless budgets; the video's, a ``<video>``'s, never has it). Each run
starts a fresh server (nothing kept from the run before); the browser runs at the
server's priority (the user's browser was on the same busy machine).
"""

from __future__ import annotations

import contextlib
import shutil
import statistics
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

from bench.common import emit, machine, parser
from harness.servers import serve_for_bench

TOKEN = "bench-review-load-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
VIDEO_ENV = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_HOME_POSE": "qn",
    "TELEROBOT_OPERATOR_TOKEN": TOKEN,
    "TELEROBOT_SIM_STARTS_AT_HOME": "true",
}
# What the page has shown, in the page's own clock (ms since its navigation started),
# polled every animation frame by the page itself. The page before issue 55 showed no
# indicator and set `window.review` once the whole timeline was there.
PROBE = """() => {
  const marks = window.__reviewLoadMarks ?? (window.__reviewLoadMarks = {});
  const now = performance.now();
  const ready = document.body && document.body.dataset.reviewReady === '1';
  const box = document.getElementById('review-loading');
  const shown = box && !box.hidden && box.getClientRects().length > 0;
  if (marks.progress === undefined && shown) marks.progress = now;
  const r = window.review;
  const drawn = r && (r.pictures ? r.pictures.drawn > 0 : r.video && r.video.readyState >= 2);
  if (marks.picture === undefined && drawn) marks.picture = now;
  const plots = r && (r.loading ? r.loading.loadedTo > 0 : ready);
  if (marks.plots === undefined && plots) marks.plots = now;
  if (marks.complete === undefined && ready) marks.complete = now;
  return marks;
}"""
POLL = """(() => {
  const probe = %s;
  const tick = () => {
    const m = probe();
    if (m.picture === undefined || m.complete === undefined) requestAnimationFrame(tick);
  };
  tick();
})()"""


def record(seconds: float, out: Path) -> dict[str, Any]:
    """A recording of ``seconds`` made by a real server with video, copied to ``out``."""
    from telerobot.client import Telerobot

    # The media worker at the server's priority: on a shared machine, at its default 10
    # it encoded 2.5 fps (321 frames in 126 s), at 0 17 fps.
    with (
        serve_for_bench(env={**VIDEO_ENV, "TELEROBOT_VIDEO_NICE": "0"}, ready=True) as (_, base),
        httpx.Client(base_url=base + "api/v1/", headers=AUTH, timeout=120) as http,
    ):
        deadline = time.monotonic() + 60
        while not http.get("video").json().get("worker_alive"):
            if time.monotonic() > deadline:
                raise RuntimeError("the media worker never came up")
            time.sleep(0.2)
        time.sleep(2.0)  # the first frames encoded
        r = http.post("recordings", json={"name": out.stem})
        r.raise_for_status()
        with Telerobot(base, TOKEN, name="bench") as robot:
            end = time.monotonic() + seconds
            k = 0
            while time.monotonic() < end:
                step = 0.002 if (k // 20) % 2 == 0 else -0.002  # back and forth, 2 s each
                with contextlib.suppress(Exception):
                    robot.move_cartesian([step, 0.0, 0.0], relative=True, wait=False)
                k += 1
                time.sleep(0.1)
        entry = http.post("recordings/active/stop").json()
        file = entry["file"]
        with http.stream("GET", f"recordings/{file}/download") as got, out.open("wb") as f:
            for chunk in got.iter_bytes():
                f.write(chunk)
        return {"file": file, "bytes": out.stat().st_size, "duration_s": entry["duration_s"]}


@contextlib.contextmanager
def serving(recording: Path) -> Iterator[str]:
    """A fresh server (video on) whose state folder holds a copy of ``recording``
    alone; its base URL."""
    with tempfile.TemporaryDirectory() as state:
        folder = Path(state) / "recordings"
        folder.mkdir()
        shutil.copy(recording, folder / recording.name)
        with serve_for_bench("--state-dir", state, env=VIDEO_ENV, ready=True) as (_, base):
            yield base


@contextlib.contextmanager
def busy(on: bool) -> Iterator[None]:
    if not on:
        yield
        return
    proc = subprocess.Popen(["stress-ng", "--cpu", "1", "--quiet"])
    try:
        time.sleep(1.0)
        yield
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def load_once(
    recording: Path, *, cpu_busy: bool, token: bool = False, timeout_s: float = 600.0
) -> dict[str, Any]:
    """One page load of ``recording`` on a fresh server; the figures of it."""
    from playwright.sync_api import sync_playwright

    from harness.chromium import ARGS

    with serving(recording) as base, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        try:
            # The browser at the server's priority, on the same machine, as the user's
            # was (not yielded as the tests' is: its own time is part of the figure).
            page = browser.new_page(viewport={"width": 1500, "height": 900})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            with busy(cpu_busy):
                page.add_init_script(POLL % PROBE)
                query = f"id={recording.name}" + (f"&token={TOKEN}" if token else "")
                page.goto(base + f"review.html?{query}", wait_until="commit")
                page.wait_for_function(
                    "() => { const m = window.__reviewLoadMarks ?? {};"
                    " return m.picture !== undefined && m.complete !== undefined; }",
                    timeout=timeout_s * 1000,
                    polling=250,
                )
            marks: dict[str, float] = page.evaluate("window.__reviewLoadMarks")
        finally:
            browser.close()
    got = {
        "first_progress_s": None if "progress" not in marks else marks["progress"] / 1000,
        "first_picture_s": marks["picture"] / 1000,
        "first_plots_s": marks["plots"] / 1000,
        "timeline_complete_s": marks["complete"] / 1000,
    }
    if errors:
        got["page_errors"] = errors[:3]
    return got


def requests_once(recording: Path) -> dict[str, float]:
    """Each read timed alone on a fresh server (nothing kept): the whole timeline, the
    first piece (a server before issue 55 ignores the range: its whole), the MP4."""
    with (
        serving(recording) as base,
        httpx.Client(base_url=base + "api/v1/recordings/", headers=AUTH, timeout=600) as http,
    ):
        out = {}
        for name, url, params in (
            ("first_piece", "timeline", {"max_points": 4000, "start_s": 0, "end_s": 10}),
            ("mp4", "video.mp4", {}),
            ("whole_timeline", "timeline", {"max_points": 4000}),
        ):
            t0 = time.perf_counter()
            r = http.get(f"{recording.name}/{url}", params=params)
            r.raise_for_status()
            out[name] = round(time.perf_counter() - t0, 2)
        return out


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--recording", type=Path, help="an MCAP a server made (else one is made)")
    p.add_argument("--seconds", type=float, default=120.0, help="the recording made: its length")
    p.add_argument("--keep", type=Path, help="save the recording made here")
    p.add_argument("--busy", action="store_true", help="one core kept busy (stress-ng --cpu 1)")
    p.add_argument("--runs", type=int, default=1, help="page loads (median figures)")
    p.add_argument("--token", action="store_true", help="the page opened with the operator token")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        made: dict[str, Any] = {}
        recording = args.recording
        if recording is None:
            recording = Path(tmp) / "review-load.mcap"
            made = record(args.seconds, recording)
            if args.keep:
                shutil.copy(recording, args.keep)
        size = recording.stat().st_size
        runs = [
            load_once(recording, cpu_busy=args.busy, token=args.token) for _ in range(args.runs)
        ]
        with busy(args.busy):
            requests = requests_once(recording)
    figures: dict[str, Any] = {}
    for key in ("first_progress_s", "first_picture_s", "first_plots_s", "timeline_complete_s"):
        values = [r[key] for r in runs if r[key] is not None]
        figures[key] = round(statistics.median(values), 2) if values else None
    figures["requests_s"] = requests
    figures["runs"] = runs
    figures["recording"] = {"file": recording.name, "bytes": size, **made}
    figures["busy"] = args.busy
    figures["token"] = args.token
    figures["machine"] = machine()
    emit(figures, args.json)


if __name__ == "__main__":
    main()
