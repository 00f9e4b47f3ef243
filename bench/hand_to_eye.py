"""Hand to eye: a key pressed in the operator page → the arm's motion on the page's
screen, the whole loop, measured by the page itself for every motion (issue 56;
docs/hand-to-eye.md).

    python -m bench.hand_to_eye [--json] [--fps 30|60] [--browser-equal] [--busy-core]
                                [--motions 200] [--width 1280 --height 720] [--camera-pixels]

Debian's Chromium (Playwright, never a downloaded browser) opens the page of a
``telerobot serve`` (simulation, video on), takes control and drives as an operator
does: hold the dead-man (Space), press a motion key (W/S, A/D, R/F, at random), hold it
``HOLD_S``, let both go, pause (random, so presses fall anywhere between exposures),
again. The simulated camera draws a motion mark beside its timecode (the tool's position
as three rulers at 0.1 mm a pixel, drivers/camera/motion_mark.py); the page
(web/src/view/handeye.ts, through ``window.telerobot.handEye``) finds in the decoded
frames the first whose mark moved and joins, per press, on its own clock:

- ``input_to_sent``: the keydown's event time → the first command after it leaves the
  page's realtime worker;
- ``sent_to_applied``: → the server's driver took it (its ACK's server time, through the
  page's ping clock sync);
- ``applied_to_exposure``: → the exposure of the first frame whose mark moved ≥ 3 px
  (0.3 mm of the tool): the arm accelerating, the camera's next exposure;
- ``exposure_to_decoded``: → that frame decoded in the page (the glass meter's worker);
- ``decoded_to_presented``: → the first frame from that exposure on presented
  (requestVideoFrameCallback's expectedDisplayTime; headless Chromium has no display,
  so a real one adds up to a refresh).

``hand_to_eye_ms`` is presented − keydown; the parts sum to it. The mark magnifies: the
tool must move ~1 mm to move one pixel of the picture itself (``mark``: the figures),
so an operator's eye sees the motion later than the mark does, by the time the tool
takes to cross that pixel. Conditions: ``--fps`` (the server's ``video_fps``), the
browser held back (default: its session and software GPU at nice 10, the media worker
at 0, as bench.browser's ``yields``) or ``--browser-equal`` (nothing reniced, the media
worker at the product's nice 10), ``--busy-core`` (stress-ng on one core);
``--send-on-frame``: the page sends a key's first command at its next animation frame,
as it did before issue 56 (it now sends at the keydown).
"""

from __future__ import annotations

import random
import secrets
import time
from typing import Any

import httpx
import numpy as np
from playwright.sync_api import Page, sync_playwright

from bench.browser import DECODER, open_operator_page
from bench.common import busy_core, emit, machine, p50_p99, parser
from harness.servers import serve_for_bench
from telerobot.drivers.camera import motion_mark

KEYS = {"x": ("KeyW", "KeyS"), "y": ("KeyA", "KeyD"), "z": ("KeyR", "KeyF")}
PARTS = (
    "input_to_sent",
    "sent_to_applied",
    "applied_to_exposure",
    "exposure_to_decoded",
    "decoded_to_presented",
)
DEADMAN_FIRST_S = (0.05, 0.15)  # Space held this long (at random) before the motion key
HOLD_S = 0.12  # the motion key held: ~6 mm at the page's default speed (0.5: 50 mm/s)
PAUSE_S = (0.3, 0.55)  # both let go this long (at random): the arm at rest again
JOG_M_S = 0.05  # the page's default speed (0.5) of its 0.1 m/s: input/loop.ts
BATCH = 20  # presses between two looks at how many motions the page has found


def directions(n: int, rng: random.Random) -> list[str]:
    """``n`` motion keys at random, each axis's keys kept near balanced (the tool wanders
    no more than a few motions from where it started: no joint limit is ever met)."""
    net = dict.fromkeys(KEYS, 0)
    out = []
    for _ in range(n):
        axis = rng.choice(list(KEYS))
        sign = rng.choice((1, -1)) if abs(net[axis]) < 3 else (-1 if net[axis] > 0 else 1)
        net[axis] += sign
        out.append(KEYS[axis][0 if sign > 0 else 1])
    return out


def drive(page: Page, keys: list[str], rng: random.Random) -> None:
    for key in keys:
        page.keyboard.down("Space")
        time.sleep(rng.uniform(*DEADMAN_FIRST_S))
        page.keyboard.down(key)
        time.sleep(HOLD_S)
        page.keyboard.up(key)
        page.keyboard.up("Space")
        time.sleep(rng.uniform(*PAUSE_S))


def mark_figures(base: str) -> dict[str, float]:
    """The mark's magnification where the tool is: metres of its motion per pixel of the
    picture itself (its depth over the left camera's focal length) against the mark's
    0.1 mm, and how long the tool takes to cross one picture pixel at the jog's speed."""
    cam = httpx.get(base + "api/v1/workcell", timeout=10).json()["cameras"][0]
    tool = np.array(httpx.get(base + "api/v1/robot/state", timeout=10).json()["position"])
    depth = float(np.array(cam["R"]) @ tool @ np.array([0, 0, 1]) + cam["t"][2])
    m_per_px = depth / float(cam["K"][0][0])
    return {
        "m_per_px": motion_mark.M_PER_PX,
        "picture_m_per_px": round(m_per_px, 6),
        "magnification": round(m_per_px / motion_mark.M_PER_PX, 1),
        "moved_px": 3,
        "jog_m_s": JOG_M_S,
        "tool_ms_per_picture_px": round(m_per_px / JOG_M_S * 1000, 1),
    }


def run(args: Any) -> dict[str, Any]:
    token = secrets.token_hex(16)
    yields = not args.browser_equal
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": str(args.width),
        "TELEROBOT_VIDEO_HEIGHT": str(args.height),
        "TELEROBOT_VIDEO_FPS": str(args.fps),
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_HOME_POSE": "qn",
    }
    if yields:
        env["TELEROBOT_VIDEO_NICE"] = "0"  # as bench.browser's yields leg
    rng = random.Random(args.seed)
    keys = directions(3 * args.motions, rng)  # at most: a starved page misses presses
    with (
        serve_for_bench(env=env, ready=True) as (_, base),
        busy_core(args.busy_core),
        sync_playwright() as pw,
    ):
        browser, page, gpu_threads, yielded_session = open_operator_page(
            pw, base, token, yields, args.camera_pixels
        )
        page.click("#take")
        page.wait_for_function(
            "window.telerobot.state && (window.telerobot.state.flags & 1)", timeout=30_000
        )
        mark = mark_figures(base)
        if args.send_on_frame:  # as before issue 56's item 3
            page.evaluate("window.telerobot.loop.driveOnKey = false")
        page.evaluate("window.telerobot.handEye.start()")
        time.sleep(1.5)  # the glass meter reads the mark from its next clock message on
        d0, t0 = page.evaluate(DECODER), time.monotonic()
        # Presses in batches until the page has found `motions` of them (a press the
        # page found no command or no motion for is counted in `missed`, not here).
        presses = 0
        while presses < len(keys):
            batch = keys[presses : presses + BATCH]
            drive(page, batch, rng)
            presses += len(batch)
            time.sleep(0.5)  # the batch's last frames presented
            found_so_far = page.evaluate("window.telerobot.handEye.motions().motions.length")
            if found_so_far >= args.motions:
                break
        time.sleep(0.5)
        d1, elapsed = page.evaluate(DECODER), time.monotonic() - t0
        found = page.evaluate("window.telerobot.handEye.motions()")
        canvas = page.evaluate(
            "(() => { const c = window.telerobot.view.canvas;"
            " return { width: c.width, height: c.height, shown: c.clientWidth }; })()"
        )
        browser.close()
    motions = found["motions"]
    whole = [m["wholeMs"] for m in motions]
    return {
        "hand_to_eye_ms": p50_p99(whole),
        "parts_ms": {p: p50_p99([m["parts"][p] for m in motions]) for p in PARTS},
        "motions": len(motions),
        "presses": presses,
        "missed": found["missed"],
        "fps_decoded": round((d1["decoded"] - d0["decoded"]) / elapsed, 2),
        # the parts' medians need not sum to the whole's; their means do:
        "mean_ms": {
            "hand_to_eye": round(float(np.mean(whole)), 2) if whole else None,
            **(
                {p: round(float(np.mean([m["parts"][p] for m in motions])), 2) for p in PARTS}
                if motions
                else {}
            ),
        },
        "mark": mark,
        "fps": args.fps,
        "width": args.width,
        "height": args.height,
        "browser": "equal" if args.browser_equal else "held back",
        "browser_session_yields": yielded_session,
        "gpu_threads_niced": gpu_threads,
        "video_nice": int(env.get("TELEROBOT_VIDEO_NICE", "10")),
        "busy_core": args.busy_core,
        "drive_on": "next frame" if args.send_on_frame else "keydown",
        "drawn": "camera pixels" if args.camera_pixels else "the box's pixels",
        "canvas": canvas,
        "decoded_width": d1["width"],
        "seconds": round(elapsed, 1),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--fps", type=int, default=30, help="the server's video_fps")
    p.add_argument("--browser-equal", action="store_true", help="nothing reniced")
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument(
        "--motions", type=int, default=200, help="pressed until this many are found (3x at most)"
    )
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--seed", type=int, default=56)
    p.add_argument(
        "--send-on-frame",
        action="store_true",
        help="the page sends a key's first command at its next animation frame (as before)",
    )
    p.add_argument(
        "--camera-pixels",
        action="store_true",
        help="the view draws every camera pixel, whatever its box shows (as before)",
    )
    args = p.parse_args()
    figures = run(args)
    emit(figures, False)
    for key in ("hand_to_eye_ms", "parts_ms", "mean_ms", "mark"):
        print(f"{key}: {figures[key]}")
    if args.json:
        import json

        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
