"""The operator client in a real browser (Debian's Chromium through Playwright)
against the real server on the simulation, video included."""

from __future__ import annotations

import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser

from tests.support import TOKEN, until
from tests.support.browser import (
    DRIVE_S,
    SHOTS_FOR_DOCS,
    assert_ball_on_the_tool,
    open_page,
    page_said,
    read_fresh_view,
    take_control,
    target,
    tool_position,
    wait,
    xr_frames_pass,
)

pytestmark = pytest.mark.browser


def test_gamepad_dead_man_drives_releasing_stops_estop_stops_observer_cannot(
    browser: Browser, server: str
) -> None:
    # First in this file: no earlier page has streamed from this server yet.
    page, errors = open_page(browser, server)
    page.click("#take")
    wait(page, "(window.telerobot.state.flags & 1) !== 0")
    start = target(server)
    page.evaluate("window.__pad.axes[1] = -0.8")  # stick forward, dead-man not held
    page.wait_for_timeout(500)
    assert target(server) == start  # nothing moves without the dead-man
    page.evaluate("window.__pad.pressed.add(5)")
    until(
        lambda: target(server) != start,
        timeout=DRIVE_S,
        what=page_said(page, "the arm moves with the dead-man held"),
    )
    page.evaluate("window.__pad.pressed.delete(5)")  # release: the arm stops
    page.wait_for_timeout(300)
    held = target(server)
    page.wait_for_timeout(600)
    assert target(server) == held
    page.click("#estop")
    wait(page, "(window.telerobot.state.flags & 4) !== 0")
    page.evaluate("window.__pad.pressed.add(5)")
    page.wait_for_timeout(600)
    assert target(server) == held  # e-stop latched: nothing moves
    assert httpx.get(server + "api/v1/safety").json()["estop"] is True
    page.evaluate("window.__pad.pressed.delete(5)")
    page.click("#reset")
    wait(page, "(window.telerobot.state.flags & 4) === 0")
    if page.locator("#release").is_visible():
        page.click("#release")
    assert errors == []
    page.close()  # one video page at a time on this machine
    # An observer page: no take-control button, and its dead-man moves nothing.
    observer, errors = open_page(browser, server, token="")
    observer.evaluate("localStorage.removeItem('telerobot.token')")
    assert observer.locator("#take").is_hidden()
    assert "observer" in (observer.locator("#role").text_content() or "")
    before = target(server)
    observer.evaluate("window.__pad.axes[1] = -0.8; window.__pad.pressed.add(5)")
    observer.wait_for_timeout(600)
    assert target(server) == before
    assert errors == []
    observer.close()


def test_page_plays_the_stereo_video_and_reports_glass_to_glass_latency(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    f0 = page.evaluate("window.telerobot.view.frames")
    wait(page, f"window.telerobot.view.frames > {f0} + 10")  # frames advance
    # Each frame's glass-to-glass latency is measured from its timecode (the figure
    # itself is bench.browser's, docs/PERFORMANCE.md: on a shared 2-core machine it
    # measures the machine's load as much as the product, so no line is drawn here):
    # every one is a real age, positive and from this session's clock (not minutes).
    page.wait_for_function("window.telerobot.glass.count > 50", timeout=60_000)
    last = np.array(page.evaluate("window.telerobot.glass.snapshot().slice(-50)"))
    assert len(last) == 50 and np.all(np.isfinite(last)), last
    assert last.min() > 0 and last.max() < 10_000, last
    assert "glass-to-glass p50" in page.locator("#latency").text_content()  # type: ignore[operator]
    assert errors == []
    page.close()


ANAGLYPH_PIXELS = """() => {
const video = document.getElementById('video');
video.pause();
window.telerobot.view.redraw();
const W = video.videoWidth / 2, H = video.videoHeight;
const crop = window.telerobot.view.croppedRows; // the timecode rows: not shown
const src = document.createElement('canvas'); src.width = 2 * W; src.height = H;
const s = src.getContext('2d'); s.drawImage(video, 0, 0);
const out = document.createElement('canvas'); out.width = W; out.height = H;
const o = out.getContext('2d'); o.drawImage(document.getElementById('view'), 0, 0);
const points = [];
for (let i = 0; i < 40; i++) {
  const x = 20 + Math.floor((i * 97) % (W - 40)), y = 40 + Math.floor((i * 53) % (H - 60));
  points.push([Array.from(s.getImageData(x, y, 1, 1).data), Array.from(s.getImageData(x + W, y, 1, 1).data),
               Array.from(o.getImageData(x, y - crop, 1, 1).data)]);
}
video.play();
return { stale: window.telerobot.view.staleMs, points };
}"""


def test_anaglyph_takes_red_from_the_left_image_and_green_blue_from_the_right(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    page.uncheck("#ar")
    page.evaluate("window.telerobot.setMode('anaglyph')")
    # Paused, drawn and read in one task: a video paused for 300 ms is stale (dimmed).
    # A loaded machine can find the view stale already (its last frame late): the read
    # says so, and is taken again once frames come.
    for _ in range(10):
        got = page.evaluate(ANAGLYPH_PIXELS)
        if got["stale"] is None:
            break
        wait(page, "window.telerobot.view.staleMs === null", timeout=20_000)
    assert got["stale"] is None, "the view stayed stale"
    result = got["points"]
    differ = 0
    for left, right, shown in result:
        assert abs(shown[0] - left[0]) <= 3, (left, right, shown)
        assert abs(shown[1] - right[1]) <= 3 and abs(shown[2] - right[2]) <= 3, (left, right, shown)
        differ += abs(left[0] - right[0]) > 20
    assert differ >= 3  # the check saw places where the two eyes really differ
    assert errors == []
    page.close()


def test_the_ar_ball_sits_where_the_ground_truth_camera_sees_the_gripper(
    browser: Browser, server: str
) -> None:
    page, _ = open_page(browser, server)
    ball = assert_ball_on_the_tool(page, server)
    # And it is drawn there as a ring in the ball's colour (the tip it marks shows
    # through), in both halves of the view, the timecode rows cropped above it.
    page.uncheck("#ghost")  # nothing else drawn over the ring
    frames = page.evaluate("window.telerobot.view.frames")
    wait(page, f"window.telerobot.view.frames > {frames + 3}")  # drawn without it
    # Read from a view showing fresh video: a stale one has "VIDEO STALE" over its
    # middle, where the ring is (a stressed run read 4 of 8 ring points under it).
    rings = read_fresh_view(
        page,
        """([l, r]) => {
        const v = document.getElementById('view'); const c = document.createElement('canvas');
        c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
        const W = v.width / 2, crop = window.telerobot.view.croppedRows;
        const radius = Number(document.getElementById('ar-size').value);
        const at = (x, y) => Array.from(g.getImageData(Math.round(x), Math.round(y - crop), 1, 1).data).slice(0, 3);
        return [[l, 0], [r, W]].map(([b, dx]) => ({
          centre: at(b[0] + dx, b[1]),
          ring: Array.from({ length: 8 }, (_, k) => [radius - 1, radius, radius + 1].map((r) => at(b[0] + dx + r * Math.cos(k * Math.PI / 4), b[1] + r * Math.sin(k * Math.PI / 4)))),
        }));
      }""",
        [ball["left"], ball["right"]],
    )

    def ball_colour(rgb: list[int]) -> bool:  # #00ff66, under the overlay's faint edges
        return max(abs(a - b) for a, b in zip(rgb, (0, 255, 102), strict=True)) <= 50

    # (the axis marker may cross the ring in a few places; each of the 8 places is read
    # at the ring's radius and a pixel either side: the overlay is drawn at half the
    # view's resolution, and a stressed run found 4 of 8 a pixel off)
    for eye in rings:
        on_ring = sum(any(ball_colour(rgb) for rgb in place) for place in eye["ring"])
        assert on_ring >= 5 and not ball_colour(eye["centre"]), (rings, ball)
    page.close()


def test_screenshots_of_each_view(browser: Browser, server: str, tmp_path: Path) -> None:
    page, errors = open_page(browser, server)
    shots = Path(SHOTS_FOR_DOCS) if SHOTS_FOR_DOCS else tmp_path
    shots.mkdir(parents=True, exist_ok=True)
    for mode in ["mono", "side-by-side", "cross-eye", "anaglyph", "anaglyph-dubois"]:
        page.evaluate(f"window.telerobot.setMode('{mode}')")
        frames = page.evaluate("window.telerobot.view.frames")
        wait(page, f"window.telerobot.view.frames > {frames + 3}")  # drawn in the new mode
        shot = shots / f"view-{mode}.png"
        shot.unlink(missing_ok=True)
        page.screenshot(path=str(shot))
        assert shot.stat().st_size > 10_000, mode
    assert errors == []
    page.close()


def test_keyboard_space_is_the_dead_man_w_drives_escape_stops_alt_arrows_align(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server)
    take_control(page)
    page.keyboard.press("Digit1")  # the base frame (the view frame is the default)
    start = target(server)
    page.click("#ar")  # a control touched: the keys still drive,
    page.click("#ar")  # and Space does not toggle it
    ar_before = page.is_checked("#ar")
    page.keyboard.down("KeyW")
    page.wait_for_timeout(500)
    assert target(server) == start  # W alone: nothing moves
    x0 = tool_position(server)[0]
    page.keyboard.down("Space")
    # W with Space held: forward along base x
    until(
        lambda: tool_position(server)[0] >= x0 + 0.005,
        timeout=DRIVE_S,
        what=page_said(page, "the arm moves with Space held"),
    )
    page.keyboard.up("Space")
    assert page.is_checked("#ar") == ar_before  # Space drove, it did not toggle the box
    page.wait_for_timeout(300)
    held = target(server)
    page.wait_for_timeout(600)
    assert target(server) == held  # Space released: stopped
    page.keyboard.up("KeyW")
    page.keyboard.press("Escape")  # the e-stop key
    wait(page, "(window.telerobot.state.flags & 4) !== 0")
    assert httpx.get(server + "api/v1/safety").json()["estop"] is True
    page.click("#reset")
    wait(page, "(window.telerobot.state.flags & 4) === 0")
    # Alt+arrows shift the right image; the shift is remembered for this viewer.
    viewer = page.evaluate("localStorage.getItem('telerobot.viewer')")
    before = httpx.get(server + f"api/v1/video/alignment?viewer={viewer}").json()
    page.keyboard.press("Alt+ArrowRight")
    page.keyboard.press("Alt+ArrowRight")
    page.keyboard.press("Alt+ArrowUp")
    expected = {"dx": before["dx"] + 2, "dy": before["dy"] - 1}
    deadline = time.monotonic() + 5
    while httpx.get(server + f"api/v1/video/alignment?viewer={viewer}").json() != expected:
        assert time.monotonic() < deadline, "the alignment was not saved"
        time.sleep(0.1)
    page.reload()
    wait(page, "window.telerobot && window.telerobot.view.frames > 0", timeout=60_000)
    assert page.locator("#align").text_content() == f"{expected['dx']}, {expected['dy']}"
    page.keyboard.press("Alt+ArrowLeft")  # leave it as it was for the other tests
    page.keyboard.press("Alt+ArrowLeft")
    page.keyboard.press("Alt+ArrowDown")
    if page.locator("#release").is_visible():
        page.click("#release")
    assert errors == []
    page.close()


# Per eye, in the WebXR framebuffer (left eye = left half of the canvas): the quad's
# extent, white timecode pixels near its top (only the left camera's image carries the
# timecode), the red block's centre across the quad, and the AR ball's green pixels.
EYES = """() => {
  const v = document.getElementById('view'); const c = document.createElement('canvas');
  c.width = v.width; c.height = v.height; const g = c.getContext('2d'); g.drawImage(v, 0, 0);
  const W = v.width / 2, H = v.height;
  return [0, 1].map((e) => {
    const d = g.getImageData(e * W, 0, W, H).data;
    let x0 = W, x1 = 0, y0 = H, y1 = 0;
    for (let y = 0; y < H; y += 2) for (let x = 0; x < W; x += 2) {
      const i = 4 * (y * W + x);
      if (d[i] + d[i + 1] + d[i + 2] > 30) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
    }
    let white = 0, red = 0, redX = 0, green = 0;
    for (let y = y0; y <= y1; y++) for (let x = x0; x <= x1; x++) {
      const i = 4 * (y * W + x), r = d[i], gr = d[i + 1], b = d[i + 2];
      if (r > 240 && gr > 240 && b > 240 && y < y0 + 0.1 * (y1 - y0)) white++;
      if (r > 150 && gr < 90 && b < 80) { red++; redX += (x - x0) / (x1 - x0); }
      if (r < 40 && gr > 220 && b > 70 && b < 140) green++;
    }
    return { width: x1 - x0, white, red, redX: red ? redX / red : -1, green };
  });
}"""


def test_webxr_each_eye_sees_its_camera_the_grip_drives_the_arm_and_contact_pulses_haptics(
    browser: Browser, server: str
) -> None:
    page, errors = open_page(browser, server, xr=True)
    take_control(page)
    page.click("#xr")
    wait(page, "window.telerobot.view.xrPresenting && window.telerobot.view.xrFrames > 5")
    left, right = page.evaluate(EYES)
    assert left["width"] > 300 and right["width"] > 300, (left, right)  # a quad in each eye
    assert left["white"] == 0 and right["white"] == 0, (left, right)  # the timecode cropped
    assert left["red"] > 100 and right["red"] > 100, (left, right)
    # A rectified pair: the block sits further right in the left camera's image.
    assert left["redX"] > right["redX"] + 0.01, (left, right)
    assert left["green"] > 20 and right["green"] > 20, (left, right)  # the AR ball, both eyes

    # The right controller: nothing moves until the grip is held; then the hand's
    # motion (forward = −z in XR) moves the gripper along base +x, scaled by the speed.
    hand = "window.__xr.controllers.right"
    # iwer marks every space as emulated (estimated); a tracked controller is not, and
    # the page ignores a hand whose position is only estimated.
    tracked = (
        f"(on) => {{ const s = {hand}.inputSource.gripSpace;"
        "s[Object.getOwnPropertySymbols(s).find((k) => k.description === '@iwer/xr-space')]"
        ".emulated = !on; }"
    )
    page.evaluate(tracked, True)
    start, p0 = target(server), tool_position(server)
    for _ in range(10):
        page.evaluate(f"{hand}.position.z -= 0.004")
        page.wait_for_timeout(50)
    assert target(server) == start
    page.evaluate(f"{hand}.updateButtonValue('squeeze', 1)")
    xr_frames_pass(page)  # the clutch anchors in the first frame that sees the grip
    for _ in range(20):
        page.evaluate(f"{hand}.position.z -= 0.004")  # 8 cm forward in all
        page.wait_for_timeout(50)
    until(
        lambda: (tool_position(server) - p0)[0] >= 0.02,
        timeout=DRIVE_S,
        what=page_said(
            page,
            lambda: (
                f"the gripper follows the hand 2 cm forward: moved {tool_position(server) - p0}"
            ),
        ),
    )
    page.evaluate(tracked, False)  # tracking lost, grip still held
    xr_frames_pass(page)
    page.wait_for_timeout(500)  # the commands already sent reach their targets
    moved = tool_position(server) - p0
    assert abs(moved[1]) < 0.3 * moved[0] and abs(moved[2]) < 0.3 * moved[0], moved.tolist()
    held = target(server)
    for _ in range(10):
        page.evaluate(f"{hand}.position.z -= 0.004")
        page.wait_for_timeout(50)
    assert target(server) == held  # an estimated position moves nothing
    page.evaluate(f"{hand}.updateButtonValue('squeeze', 0)")
    page.evaluate(tracked, True)
    xr_frames_pass(page)
    for _ in range(10):
        page.evaluate(f"{hand}.position.z -= 0.004")
        page.wait_for_timeout(50)
    assert target(server) == held  # grip released: the hand moves nothing

    # Contact: a scripted move presses the tool 1 mm into the table (the REST client
    # takes the lease over). The gamepad rumbles and the controller pulses, in
    # proportion to the force; away from the contact they stop.
    page.evaluate(
        f"window.__pulses = []; const h = {hand}.inputSource.gamepad.hapticActuators[0];"
        "const pulse = h.pulse.bind(h); h.pulse = (v, d) => (window.__pulses.push(v), pulse(v, d));"
        "window.__rumble.length = 0;"
    )
    rest = httpx.Client(base_url=server + "api/v1/", headers={"Authorization": f"Bearer {TOKEN}"})
    table = next(
        b for b in httpx.get(server + "api/v1/workcell").json()["boxes"] if b["name"] == "table"
    )
    top = table["centre"][2] + table["size"][2] / 2

    def move_to(z: float) -> None:
        # (The script's lease lapses with its dead-man between moves: take it each time.)
        lease = rest.post("lease", json={"name": "script", "force": True})
        assert lease.status_code == 200, lease.text
        rest.headers["X-Client-Id"] = lease.json()["client_id"]
        r = rest.post(
            "robot/move",
            json={"space": "cartesian", "mode": "absolute", "position": [0.8, 0.2, z]},
        )
        assert r.status_code == 200, r.text

    move_to(top + 0.02)
    move_to(top - 0.001)
    wait(page, "window.__pulses.length > 3 && window.__rumble.length > 3")
    force = httpx.get(server + "api/v1/force").json()["latest"]
    strength = float(np.linalg.norm(force["values"][:3])) / 60.0
    assert 0.1 < strength < 1
    assert page.evaluate("window.__pulses.at(-1)") == pytest.approx(strength, abs=0.1)
    assert page.evaluate("window.__rumble.at(-1)") == pytest.approx(strength, abs=0.1)
    move_to(top + 0.02)
    page.wait_for_timeout(300)
    counts = page.evaluate("[window.__pulses.length, window.__rumble.length]")
    page.wait_for_timeout(500)
    assert page.evaluate("[window.__pulses.length, window.__rumble.length]") == counts
    rest.delete("lease")
    assert errors == []
    page.close()


def test_the_calibration_page_fits_both_cameras_from_clicks_and_the_ar_view_follows(
    browser: Browser, server: str
) -> None:
    page = browser.new_page(viewport={"width": 1700, "height": 900})
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("console", lambda msg: errors.append(msg.text) if msg.type == "error" else None)
    page.goto(server + f"calibration.html?token={TOKEN}")
    page.wait_for_function(
        "window.calibration && document.getElementById('video').videoWidth > 0", timeout=60_000
    )
    page.wait_for_timeout(500)
    page.click("#freeze")
    cell = httpx.get(server + "api/v1/workcell").json()
    assert "Click fiducial 1 of 12 in the LEFT image" in page.locator("#prompt").inner_text()
    for cam in cell["cameras"]:  # click every fiducial where the camera sees it
        P = np.array(cam["P"])
        box = page.locator(f"#{cam['name']}").bounding_box()
        assert box is not None
        scale = box["width"] / cam["width"]
        for X in cell["fiducials"]:
            u, v, w = P @ np.array([*X, 1.0])
            page.mouse.click(box["x"] + u / w * scale, box["y"] + v / w * scale)
    assert page.locator("#prompt").inner_text() == "All fiducials clicked: compute."
    page.click("#compute")
    wait(page, "window.calibration.state.cameras.every((c) => c.source === 'calibrated')")
    state = httpx.get(server + "api/v1/calibration").json()
    assert [c["method"] for c in state["cameras"]] == ["dlt", "dlt"]
    assert all(c["rms_px"] < 1.5 for c in state["cameras"]), state["cameras"]
    assert "rms" in page.locator("#results").inner_text()
    # The fitted frame is drawn over the image: the x axis (red) from fiducial 1 to 2.
    P = np.array(state["cameras"][0]["P"])
    (u0, v0, w0), (u1, v1, w1) = (P @ np.array([*cell["fiducials"][i], 1.0]) for i in (0, 1))
    mid = ((u0 / w0 + u1 / w1) / 2, (v0 / w0 + v1 / w1) / 2)
    rgba = page.evaluate(
        "([u, v]) => Array.from(document.getElementById('left').getContext('2d')"
        ".getImageData(Math.round(u) - 1, Math.round(v) - 1, 3, 3).data)",
        list(mid),
    )
    assert any(rgba[i] > 200 and rgba[i + 1] < 100 for i in range(0, len(rgba), 4)), rgba
    # The ChArUco flow: the simulated cameras are shown a board, then the same clicks
    # give each camera's pose with those intrinsics.
    page.click("#charuco")
    wait(page, "window.calibration.state.intrinsics_pending.length === 2", timeout=60_000)
    assert page.locator("input[value=charuco]").is_checked()
    page.click("#compute")
    wait(page, "window.calibration.state.cameras.every((c) => c.method === 'charuco')")
    state = httpx.get(server + "api/v1/calibration").json()
    assert all(c["rms_px"] < 1.5 for c in state["cameras"]), state["cameras"]
    assert state["baseline_m"] == pytest.approx(0.12, rel=0.1)
    assert "stereo baseline" in page.locator("#results").inner_text()
    assert errors == []
    page.close()
    # The operator page projects the AR ball with the calibration: a fit whose clicks
    # sit 20 px to the right puts the ball 20 px to the right.
    auth = {"Authorization": f"Bearer {TOKEN}"}
    try:
        for cam in cell["cameras"]:
            P = np.array(cam["P"])
            uvw = np.hstack([cell["fiducials"], np.ones((12, 1))]) @ P.T
            pixels = uvw[:, :2] / uvw[:, 2:] + [20.0, 0.0]
            r = httpx.post(
                server + "api/v1/calibration/fit",
                json={"camera": cam["name"], "method": "dlt", "points": cell["fiducials"],
                      "pixels": pixels.tolist()},
                headers=auth,
            )  # fmt: skip
            assert r.status_code == 200, r.text
        page, _ = open_page(browser, server)
        page.wait_for_timeout(300)
        ball = page.evaluate("window.telerobot.ball")
        tool = np.array(httpx.get(server + "api/v1/robot/state").json()["position"] + [1.0])
        for cam, got in zip(cell["cameras"], (ball["left"], ball["right"]), strict=True):
            u, v, w = np.array(cam["P"]) @ tool
            assert got[0] - u / w == pytest.approx(20.0, abs=2.0)
            assert got[1] - v / w == pytest.approx(0.0, abs=2.0)
        page.close()
    finally:
        httpx.delete(server + "api/v1/calibration", headers=auth)
