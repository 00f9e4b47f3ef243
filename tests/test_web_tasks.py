"""Tasks on the operator page, in a real browser against the real server: a
move taught through REST with the real recorder (an episode of a recording), then on
the page: the episode's path previewed in cyan in both eyes where the cameras see it,
before anything runs; the task run from the page follows it (the server's tool reaches
the episode's end), pauses and resumes, shows its progress and its end, and control
comes back to the page; from the path's end, Run is refused and "Approach first"
(confirmed) runs it anyway. On an SO-101 server, a PUMA's recording is greyed out,
saying so (it used to be offered)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Page

from tests.support import TOKEN, until
from tests.support.browser import (
    NO_VIDEO,
    open_page,
    page_said,
    read_fresh_view,
    take_control,
    tool_position,
    wait,
)
from tests.support.servers import serving

pytestmark = pytest.mark.browser
AUTH = {"Authorization": f"Bearer {TOKEN}"}
DOWN = 0.02  # m: the taught move (the per-command limit)

# Per eye, around each given camera pixel (x, y): how many pixels within ±r are cyan
# (the path's colour), read back from the shown canvas (side by side: the right eye's
# image on the right half; the first croppedRows rows of each camera image not shown).
CYAN_NEAR = """([eyes, r]) => {
  const v = document.getElementById('view'); const c = document.createElement('canvas');
  c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
  const W = v.width / 2, crop = window.telerobot.view.croppedRows;
  return eyes.map((points, eye) => points.map(([x, y]) => {
    const d = g.getImageData(Math.round(x + eye * W - r), Math.round(y - crop - r), 2 * r + 1, 2 * r + 1).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) if (d[i] < 90 && d[i + 1] > 170 && d[i + 2] > 170) n++;
    return n;
  }));
}"""


def settle_at(server: str, goal: np.ndarray, tol: float = 0.001, timeout: float = 20) -> None:
    deadline = time.monotonic() + timeout
    while np.linalg.norm(tool_position(server) - goal) > tol:
        assert time.monotonic() < deadline, (tool_position(server), goal)
        time.sleep(0.05)


def teach(server: str) -> tuple[str, np.ndarray, np.ndarray]:
    """Record an episode of a 2 cm move down through REST; the tool back at its start.
    Returns the recording's file, the start and the end position."""
    rest = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)
    cid = rest.post("lease", json={"name": "teacher", "force": True}).json()["client_id"]
    h = {"X-Client-Id": cid}
    start = tool_position(server)
    assert rest.post("recordings", json={"name": "web-task"}).status_code == 200
    assert rest.post("recordings/active/episodes", json={"task": "push down"}).status_code == 200
    time.sleep(0.3)  # some states at rest before the move (not a condition)
    move = {"space": "cartesian", "mode": "incremental", "position": [0.0, 0.0, -DOWN]}
    r = rest.post("robot/move", json=move, headers=h)
    assert r.status_code == 200, r.text
    end = start + [0.0, 0.0, -DOWN]
    settle_at(server, end)
    time.sleep(0.3)  # and some at rest after it
    r = rest.post("recordings/active/episodes/end", json={"success": True})
    assert r.status_code == 200, r.text
    rec = rest.post("recordings/active/stop").json()["file"]
    back = {"space": "cartesian", "mode": "absolute", "position": start.tolist()}
    assert rest.post("robot/move", json=back, headers=h).status_code == 200
    settle_at(server, start)
    rest.delete("lease", headers=h)
    return rec, start, end


def project(P: list[list[float]], points: np.ndarray) -> np.ndarray:
    uvw = np.hstack([points, np.ones((len(points), 1))]) @ np.array(P).T
    return uvw[:, :2] / uvw[:, 2:]


def cyan_near(page: Page, eyes: list[np.ndarray], r: int = 4) -> list[list[int]]:
    frames = page.evaluate("window.telerobot.view.frames")
    wait(page, f"window.telerobot.view.frames > {frames + 3}")  # the overlay as it is now
    return read_fresh_view(page, CYAN_NEAR, [[e.tolist() for e in eyes], r])


def test_an_episode_previewed_in_both_eyes_runs_from_the_page_and_hands_control_back(
    browser: Browser, server: str
) -> None:
    rec, start, end = teach(server)
    page, errors = open_page(browser, server)
    page.evaluate("window.telerobot.setMode('side-by-side')")
    page.uncheck("#ar")  # nothing else drawn where the path is
    page.uncheck("#ghost")
    take_control(page)
    wait(
        page,
        f"[...document.querySelectorAll('#task-recording option')].some((o) => o.value === '{rec}')",
    )
    page.select_option("#task-recording", rec)
    page.select_option("#task-episode", "0")

    # The path's points in each camera's pixels: none of its cyan before the preview.
    cameras = httpx.get(server + "api/v1/calibration").json()["cameras"]
    line = start + np.linspace(0, 1, 9)[:, None] * (end - start)
    eyes = [project(cam["P"], line) for cam in cameras[:2]]
    assert np.linalg.norm(eyes[0][0] - eyes[0][-1]) > 5  # the move is seen in the image
    before = cyan_near(page, eyes)
    assert all(n == 0 for eye in before for n in eye), before

    page.click("#task-preview")
    wait(page, "window.telerobot.tasks.path.shown")
    shown = np.array(page.evaluate("window.telerobot.tasks.path.points"))
    assert np.linalg.norm(shown[0] - start) < 0.002 and np.linalg.norm(shown[-1] - end) < 0.002
    after = cyan_near(page, eyes)
    for eye in after:  # cyan along the whole path, in both eyes
        assert sum(n > 0 for n in eye) >= 8, after
    assert page.evaluate("window.telerobot.tasks.task") is None  # previewed, not run
    assert np.linalg.norm(tool_position(server) - start) < 0.001

    # Run: the task takes the lease, the tool follows the path, control comes back.
    page.fill("#task-speed", "0.3")
    page.click("#task-run")
    wait(page, "window.telerobot.tasks.task !== null", timeout=20_000)
    # Paused, it holds still; resumed, it goes on.
    page.click("#task-pause")
    wait(page, "window.telerobot.tasks.task.state === 'paused'")
    assert page.is_visible("#task-resume") and not page.is_visible("#task-pause")
    held = tool_position(server)
    page.wait_for_timeout(600)
    assert np.linalg.norm(tool_position(server) - held) < 0.0005
    page.click("#task-resume")
    wait(page, "window.telerobot.tasks.task.state !== 'paused'")
    seen: set[str] = set()
    progress: list[float] = []
    deadline = time.monotonic() + 60
    while True:
        view = page.evaluate("window.telerobot.tasks.task")
        seen.add(view["state"])
        progress.append(page.evaluate("document.getElementById('task-progress').value"))
        if view["state"] in ("done", "stopped", "aborted"):
            break
        assert time.monotonic() < deadline, view
        time.sleep(0.1)
    assert view["state"] == "done", (view, page.locator("#messages").inner_text())
    assert any(0 < p < 1 for p in progress), (seen, progress)
    assert np.linalg.norm(tool_position(server) - end) < 0.003
    wait(page, "document.getElementById('task-progress').value === 1")
    assert "done" in page.locator("#task-state").inner_text()
    wait(page, "(window.telerobot.state.flags & 1) !== 0", timeout=10_000)  # control back
    assert page.evaluate("document.getElementById('control-alert').hidden")  # never "lost"

    # From the path's end (2 cm away) Run is refused; Approach first, confirmed, runs it.
    page.click("#task-run")
    wait(page, "!document.getElementById('task-approach').hidden")
    assert "first pose" in page.locator("#messages").inner_text()
    # The panel says the server's reason by the button, which can be pressed, and the
    # approach is drawn (dashed amber, from the tool to the path's start) before the
    # operator is asked (before, a disabled button and no reason).
    said = page.locator("#task-reason").inner_text()
    assert said.startswith("Run refused: the tool is") and "first pose" in said, said
    assert page.is_enabled("#task-approach")
    lead = np.array(page.evaluate("window.telerobot.tasks.path.approach"))
    assert len(lead) >= 2, lead
    assert np.linalg.norm(lead[0] - end) < 0.005 and np.linalg.norm(lead[-1] - start) < 0.002
    asked: list[str] = []
    page.once("dialog", lambda d: (asked.append(d.message), d.accept()))
    page.click("#task-approach")
    wait(page, f"window.telerobot.tasks.task.id !== '{view['id']}'", timeout=20_000)
    assert len(asked) == 1 and "from the task's first pose" in asked[0], asked
    assert "slow joint move" in asked[0], asked
    wait(
        page,
        "['done', 'stopped', 'aborted'].includes(window.telerobot.tasks.task.state)",
        timeout=90_000,
    )
    final = page.evaluate("window.telerobot.tasks.task")
    assert final["state"] == "done", (final, page.locator("#messages").inner_text())
    until(
        lambda: np.linalg.norm(tool_position(server) - end) < 0.003,
        what=page_said(page, "the approached task ends at the episode's end"),
    )
    wait(page, "(window.telerobot.state.flags & 1) !== 0", timeout=10_000)
    page.click("#task-clear")
    wait(page, "!window.telerobot.tasks.path.shown")
    page.click("#release")
    # The one refused start is the browser's own console line for its 422; nothing else.
    refused = [e for e in errors if "status of 422" in e]
    assert len(refused) == 1 and len(errors) == 1, errors
    page.close()


def record_an_episode(server: str, name: str) -> str:
    """A recording with one episode (the arm at rest), through REST; its file."""
    rest = httpx.Client(base_url=server + "api/v1/", headers=AUTH, timeout=30)
    assert rest.post("recordings", json={"name": name}).status_code == 200
    assert rest.post("recordings/active/episodes", json={"task": "stay"}).status_code == 200
    time.sleep(0.3)  # some states in it (not a condition)
    assert rest.post("recordings/active/episodes/end", json={"success": True}).status_code == 200
    file: str = rest.post("recordings/active/stop").json()["file"]
    return file


def test_a_recording_of_another_arm_model_is_greyed_out_saying_so(
    browser: Browser, tmp_path: Path
) -> None:
    state = ("--state-dir", str(tmp_path))  # both servers' recordings in one folder
    with serving(NO_VIDEO, *state) as puma:
        theirs = record_an_episode(puma, "puma-teach")
    so101_env = {**NO_VIDEO, "TELEROBOT_ROBOT_MODEL": "so101", "TELEROBOT_HOME_POSE": "ready"}
    with serving(so101_env, *state) as base:
        ours = record_an_episode(base, "so101-teach")  # the newest: listed first
        listed = {r["file"]: r["robot_model"] for r in httpx.get(base + "api/v1/recordings").json()}
        assert listed == {theirs: "puma560", ours: "so101"}, listed
        page, errors = open_page(browser, base, video=False)
        take_control(page)
        option = f"#task-recording option[value={json.dumps(theirs)}]"
        wait(page, f"document.querySelector({json.dumps(option)}) !== null")
        assert page.locator(option).is_disabled()
        text = page.locator(option).inner_text()
        assert text.endswith("another arm (puma560)"), text
        title = page.locator(option).get_attribute("title") or ""
        assert "this server drives the SO-101 (so101)" in title, title
        assert page.input_value("#task-recording") == ours  # its own is the one chosen
        wait(page, "!document.getElementById('task-run').disabled")
        page.click("#release")
        assert errors == []
        page.close()
