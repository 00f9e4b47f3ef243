"""A page holding control with no key pressed, in Debian's headless Chromium, against
``telerobot serve`` with video: how often the dead-man halts the arm, and whose the
stalls were (on a busy 2-core machine the page went HALTED every ~2 s).

    python -m bench.held_control [--json] [--seconds 60] [--busy-core] [--no-video]
                                 [--no-yield-gpu] [--python-client] [--drive]

``--busy-core`` keeps one core busy (Debian's stress-ng) for the run, as
``make test-slow-machine`` does. Chromium's software GPU process is niced as the test
suite does (``harness.chromium.yield_software_gpu``) unless ``--no-yield-gpu`` (a user's
browser is not). Figures: ``deadman_halts_per_min`` (the server's count with the lease
kept), ``lease_lost`` (control lost and taken again by the bench), the worker's own
heartbeat timer lateness sampled every 0.2 s (``timer_late_ms_max``, ``_p50``: the
page's rolling worst of 3 s, so p50 is of those), the worst gap between the worker's
messages as sent, sampled the same way (``beat_gap_ms_max``, ``beat_gaps_over_150ms``:
samples over the dead-man's limit), its timer's firings that sent nothing by reason
(``beat_skips``), the sessions it resumed on a new connection (``resumes``), and what
the page's halt alerts said (``halts_said_busy``: this computer;
``halts_said_network``: the network or server).
The page's main thread, as the worker sees it: its own 100 ms timer's longest gap
(``main_timer_gap_ms_max``; ``main_timer_gaps_over_1s``: the worker's PAGE_SILENCE_MS,
past which it stops the heartbeats) and its long tasks (``main_long_tasks``,
``main_long_task_ms_max``).
``--drive``: the operator drives instead of holding still: Space (the dead-man) and A
held throughout, then D, turned every ``DRIVE_FLIP_S`` (back and forth, within reach);
``drive_mm_per_s`` is the tool's path (``/robot/state`` every 0.2 s) over the run, the
figure to compare quiet and busy: what the operator still gets done.
``--python-client``: no browser; a Python client (harness.wsclient) takes the lease and
sends a HEARTBEAT every 50 ms, as the page's worker does: the server's share of the
halts.
"""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import time

import httpx
import numpy as np
from playwright.sync_api import sync_playwright

from bench.common import busy_core, emit, machine, parser
from harness.chromium import ARGS, yield_software_gpu
from harness.servers import serve_for_bench
from harness.wsclient import RealtimeClient
from telerobot.protocol import messages as m

DRIVE_FLIP_S = 2.0
# The view's draws, those put off until the GPU had finished the one before, and the
# frames never drawn (a newer one came meanwhile; null: a page without the pacer).
DRAWN = (
    "[window.telerobot.view.renders, window.telerobot.view.pacer?.waited ?? null,"
    " window.telerobot.view.pacer?.skipped ?? null]"
)


def safety_halts(base: str) -> int:
    return int(httpx.get(base + "api/v1/safety").json()["deadman_halts"])


async def python_client(base: str, token: str, seconds: float) -> dict[str, float]:
    """The lease held by heartbeats every 50 ms from a Python client: halts, and the
    longest gap between two heartbeats as sent."""
    client = await RealtimeClient.connect(base.replace("http", "ws", 1) + "ws", token)
    await client.take_lease()

    async def drain() -> None:
        while True:
            await client.ws.recv()

    reader = asyncio.create_task(drain())
    halts0 = await asyncio.to_thread(safety_halts, base)
    t0 = last = time.monotonic()
    gap = 0.0
    while time.monotonic() - t0 < seconds:
        await asyncio.sleep(0.05)
        now = time.monotonic()
        gap, last = max(gap, now - last), now
        await client.ws.send(m.encode(m.HEARTBEAT, client.next_seq(), 0.0))
    elapsed = time.monotonic() - t0
    halts = await asyncio.to_thread(safety_halts, base) - halts0
    reader.cancel()
    await client.close()
    return {
        "seconds": round(elapsed, 1),
        "deadman_halts_per_min": halts * 60.0 / elapsed,
        "deadman_halts": halts,
        "heartbeat_gap_ms_max": gap * 1000.0,
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=60.0)
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument("--no-video", action="store_true")
    p.add_argument("--no-yield-gpu", action="store_true", help="leave Chromium's GPU at nice 0")
    p.add_argument("--python-client", action="store_true", help="no browser: a Python client")
    p.add_argument("--drive", action="store_true", help="hold Space+A/D: the path driven")
    args = p.parse_args()
    token = secrets.token_hex(16)
    env = {"TELEROBOT_OPERATOR_TOKEN": token, "TELEROBOT_VIDEO": str(not args.no_video).lower()}
    if args.python_client:
        with serve_for_bench(env=env) as (_, base), busy_core(args.busy_core):
            figures = asyncio.run(python_client(base, token, args.seconds))
        figures |= {"busy_core": args.busy_core, "video": not args.no_video}
        emit({**figures, "machine": machine()}, args.json)
        return
    late: list[float] = []
    gaps: list[float] = []
    said = {"busy": 0, "network": 0}
    lease_lost = 0
    with (
        serve_for_bench(env=env) as (_, base),
        sync_playwright() as pw,
        busy_core(args.busy_core),
    ):
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        page = browser.new_page(viewport={"width": 1600, "height": 900})
        page.goto(base + f"?token={token}")
        page.wait_for_function(
            "window.telerobot && window.telerobot.state", timeout=90_000, polling=200
        )
        if not args.no_video:
            page.wait_for_function("window.telerobot.view.frames > 10", timeout=90_000, polling=200)
        if not args.no_yield_gpu:
            yield_software_gpu()
        # Every alert the page shows, as it shows it (a halt's is gone within ~100 ms
        # once heartbeats come: polling would miss most).
        page.evaluate("window.telerobot.control.recordAlerts()")
        # The page's main thread, as the worker sees it: its own 100 ms timer's gaps (the
        # check-ins are sent from such a timer) and its long tasks.
        page.evaluate(
            """() => { const m = window.__main = {gaps: [], long: []};
              let last = performance.now();
              setInterval(() => {
                const t = performance.now(); m.gaps.push(t - last); last = t; }, 100);
              new PerformanceObserver((l) => {
                for (const e of l.getEntries()) m.long.push(e.duration); })
                .observe({entryTypes: ["longtask"]}); }"""
        )
        page.click("#take")
        page.wait_for_function("(window.telerobot.state.flags & 1) !== 0", timeout=30_000)
        halts0 = httpx.get(base + "api/v1/safety").json()["deadman_halts"]
        frames0 = page.evaluate("window.telerobot.view.frames")
        drawn0 = page.evaluate(DRAWN)
        t0 = time.monotonic()
        had = True
        path_m, last_pos, key = 0.0, None, ""
        if args.drive:
            page.keyboard.down("Space")
        while time.monotonic() - t0 < args.seconds:
            time.sleep(0.2)
            if args.drive:
                want = "a" if int((time.monotonic() - t0) / DRIVE_FLIP_S) % 2 == 0 else "d"
                if want != key:
                    if key:
                        page.keyboard.up(key)
                    page.keyboard.down(want)
                    key = want
                pos = np.array(httpx.get(base + "api/v1/robot/state").json()["position"])
                if last_pos is not None:
                    path_m += float(np.linalg.norm(pos - last_pos))
                last_pos = pos
            flags, lateness, gap = page.evaluate(
                "[window.telerobot.state?.flags ?? 0, window.telerobot.client.timerLateMs,"
                " window.telerobot.client.beatGapMs]"
            )
            late.append(float(lateness))
            gaps.append(float(gap))
            if not flags & 1:  # control lost: counted once, taken again
                lease_lost += had
                had = False
                with contextlib.suppress(Exception):
                    page.click("#take", timeout=2_000)
            else:
                had = True
        elapsed = time.monotonic() - t0
        if args.drive:
            page.keyboard.up(key)
            page.keyboard.up("Space")
        for alert in page.evaluate("window.telerobot.control.alerts"):
            if alert and alert.startswith("ARM HALTED"):
                said["busy" if "too busy" in alert else "network"] += 1
        halts = httpx.get(base + "api/v1/safety").json()["deadman_halts"] - halts0
        main = page.evaluate("window.__main")
        skips, resumes = page.evaluate(
            "[window.telerobot.client.beatSkips, window.telerobot.client.resumes]"
        )
        frames = page.evaluate("window.telerobot.view.frames") - frames0
        drawn = [
            b - a if a is not None else None
            for a, b in zip(drawn0, page.evaluate(DRAWN), strict=True)
        ]
        browser.close()
    figures = {
        "seconds": round(elapsed, 1),
        "deadman_halts_per_min": halts * 60.0 / elapsed,
        "deadman_halts": halts,
        "halts_said_busy": said["busy"],
        "halts_said_network": said["network"],
        "lease_lost": lease_lost,
        "timer_late_ms_max": max(late) if late else None,
        "timer_late_ms_p50": float(np.median(late)) if late else None,
        "beat_gap_ms_max": max(gaps) if gaps else None,
        "beat_gaps_over_150ms": sum(g > 150 for g in gaps),
        "beat_skips": skips,
        "resumes": resumes,
        "main_timer_gap_ms_max": max(main["gaps"], default=None),
        "main_timer_gaps_over_1s": sum(g > 1000 for g in main["gaps"]),
        "main_long_tasks": len(main["long"]),
        "main_long_task_ms_max": max(main["long"], default=None),
        "fps": None if args.no_video else frames / elapsed,
        "drawn_fps": None if args.no_video else drawn[0] / elapsed,
        "draws_waited_for_gpu": drawn[1],
        "frames_not_drawn": drawn[2],
        "drive_mm_per_s": path_m * 1000.0 / elapsed if args.drive else None,
        "busy_core": args.busy_core,
        "video": not args.no_video,
        "yield_gpu": not args.no_yield_gpu,
    }
    emit({**figures, "machine": machine()}, args.json)


if __name__ == "__main__":
    main()
