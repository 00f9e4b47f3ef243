"""The stereo video in a real browser: Debian's headless Chromium receives it from
``telerobot serve`` (simulation, 2×1280×720 at 30 fps by default) for 60 s a leg.

    python -m bench.browser [--json] [--seconds 60] [--width 1280 --height 720] [--busy-core]
                            [--legs both|yields|equal]

Two legs, each with a server and a browser of its own, one after the other (both by
default; the JSON has ``yields`` and ``equal``, each with every figure below):

- ``equal`` — the README's quick start as shipped: ``make run`` and the page in a browser
  on the same machine. Nothing is reniced: the browser's session, its software GPU and
  the server share the CPU evenly, and the media worker runs at the product's default
  niceness (10, ``TELEROBOT_VIDEO_NICE``). This is what a new user sees.
- ``yields`` — the operator's browser on another machine, modelled on this one: the
  browser's session and its software GPU at nice 10 (``yield_browser_session``,
  ``yield_software_gpu``) and the media worker at nice 0, so the browser gets what the
  server leaves. A tuned condition: quote it beside ``equal``, never alone.

fps: video frames the page rendered per second (requestVideoFrameCallback).
Latency: capture → the decoded frame in the page, for every frame, from the timecode
in the picture (read from the decoder's own frame) on the server's clock through the
page's ping clock sync. Headless Chromium presents frames without a display, so
"presented" is not measurable here; a real display adds up to one refresh.

Beside them, over the same window: the frames the server encoded
(``server_frames_encoded``), the page's decoder's own counts from getStats
(``frames_received``, ``frames_decoded``, ``frames_dropped``), the peers re-negotiated
(``renegotiations``) and the width it ended on decoding (its video layer), which say where frames
that were not measured went. ``--busy-core`` keeps one core busy (stress-ng) meanwhile.
Headless Chromium draws with SwiftShader here (no GPU): on a machine with graphics
hardware the page's drawing takes far less CPU than either leg gives it.
"""

from __future__ import annotations

import argparse
import json
import secrets
import time
from typing import Any

import httpx
import numpy as np
from playwright.sync_api import Browser, Page, Playwright, sync_playwright

from bench.common import busy_core, emit, machine, parser
from harness.chromium import ARGS, yield_browser_session, yield_software_gpu
from harness.servers import serve_for_bench

# The page's decoder's counts for its video, from getStats (inbound-rtp, video).
DECODER = """async () => {
  const stats = await window.telerobot.video.stats();
  const out = { received: 0, decoded: 0, dropped: 0, width: 0, jitterDelay: 0, jitterEmitted: 0,
    decodeTime: 0, processingDelay: 0, assemblyTime: 0, assembled: 0 };
  out.renegotiations = window.telerobot.video.renegotiations;
  if (!stats) return out;
  stats.forEach((r) => {
    if (r.type === "inbound-rtp" && r.kind === "video") {
      out.received = r.framesReceived || 0;
      out.decoded = r.framesDecoded || 0;
      out.dropped = r.framesDropped || 0;
      out.width = r.frameWidth || 0;
      out.jitterDelay = r.jitterBufferDelay || 0;
      out.jitterEmitted = r.jitterBufferEmittedCount || 0;
      out.decodeTime = r.totalDecodeTime || 0;
      out.processingDelay = r.totalProcessingDelay || 0;
      out.assemblyTime = r.totalAssemblyTime || 0;
      out.assembled = r.framesAssembledFromMultiplePackets || 0;
    }
  });
  return out;
}"""


def server_frames(base: str) -> int:
    """Frames the server's media worker has encoded so far (GET /api/v1/video)."""
    return int(server_stats(base)["frames_encoded"])


def server_stats(base: str) -> dict[str, Any]:
    stats: dict[str, Any] = httpx.get(base + "api/v1/video", timeout=10).json()["stats"]
    return stats


def per_frame_ms(
    d0: dict[str, float], d1: dict[str, float], total: str, count: str
) -> float | None:
    """A getStats total (s) over its count, between two reads, in ms per frame."""
    n = d1[count] - d0[count]
    return (d1[total] - d0[total]) / n * 1000.0 if n > 0 else None


def open_operator_page(
    pw: Playwright, base: str, token: str, yields: bool, camera_pixels: bool = False
) -> tuple[Browser, Page, int, bool]:
    """Debian's Chromium with the operator page (1600×900), showing video; ``yields``:
    its session and software GPU at nice 10 (the browser modelled as on another
    machine); ``camera_pixels``: its view draws every camera pixel, whatever its box
    shows (as before issue 56; the page draws the box's). Returns the browser, the page,
    the GPU threads reniced and whether the session was."""
    browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
    page = browser.new_page(viewport={"width": 1600, "height": 900})
    if camera_pixels:
        page.add_init_script("window.telerobotDrawAtCameraPixels = true;")
    page.goto(base + f"?token={token}")
    gpu_threads = yield_software_gpu() if yields else 0
    yielded_session = yield_browser_session() if yields else False
    page.wait_for_function(
        "window.telerobot && window.telerobot.view.frames > 30", timeout=60_000, polling=200
    )
    return browser, page, gpu_threads, yielded_session


LEGS = {"yields": True, "equal": False}


def run_leg(args: argparse.Namespace, yields: bool) -> dict[str, Any]:
    """One leg: a server, a browser with the page, ``args.seconds`` of figures."""
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": str(args.width),
        "TELEROBOT_VIDEO_HEIGHT": str(args.height),
        "TELEROBOT_OPERATOR_TOKEN": token,
    }
    if yields:
        # The robot side's media worker at nice 0: with the browser modelled as remote,
        # nothing on this machine should hold the encoder back.
        env["TELEROBOT_VIDEO_NICE"] = "0"
    with (
        serve_for_bench(env=env) as (_, base),
        busy_core(args.busy_core),
        sync_playwright() as pw,
    ):
        browser, page, gpu_threads, yielded_session = open_operator_page(pw, base, token, yields)
        time.sleep(3)  # past the first keyframe and the clock sync
        f0, n0, d0, e0, t0 = (
            page.evaluate("window.telerobot.view.frames"),
            page.evaluate("window.telerobot.glass.total"),
            page.evaluate(DECODER),
            server_frames(base),
            time.monotonic(),
        )
        latencies: list[float] = []
        while time.monotonic() - t0 < args.seconds:
            time.sleep(min(5.0, args.seconds))
            # The page keeps the last 900 figures: collect the new ones every 5 s (at
            # most 150 at 30 fps), read together with the running total.
            snap, total = page.evaluate(
                "[window.telerobot.glass.snapshot(), window.telerobot.glass.total]"
            )
            new = total - n0 - len(latencies)
            latencies += snap[len(snap) - min(len(snap), new) :] if new > 0 else []
        frames = page.evaluate("window.telerobot.view.frames") - f0
        d1, enc = page.evaluate(DECODER), server_stats(base)
        e1 = int(enc["frames_encoded"])
        elapsed = time.monotonic() - t0
        browser.close()
    lat = np.array(latencies) if latencies else np.array([float("nan")])
    return {
        "fps": frames / elapsed,
        "latency_p50_ms": float(np.percentile(lat, 50)),
        "latency_p99_ms": float(np.percentile(lat, 99)),
        "latency_samples": len(latencies),
        "latencies": latencies,
        "seconds": elapsed,
        "server_frames_encoded": e1 - e0,
        # across a re-negotiation the new peer's counts start again: then these are low
        "frames_received": d1["received"] - d0["received"],
        "frames_decoded": d1["decoded"] - d0["decoded"],
        "frames_dropped": d1["dropped"] - d0["dropped"],
        "renegotiations": d1["renegotiations"] - d0["renegotiations"],
        "decoded_width": d1["width"],
        # Where the latency goes (means per frame over the window, from getStats; the
        # encoder's percentiles from the server's own figures since it started):
        "jitter_buffer_ms": per_frame_ms(d0, d1, "jitterDelay", "jitterEmitted"),
        "decode_ms": per_frame_ms(d0, d1, "decodeTime", "decoded"),
        "processing_ms": per_frame_ms(d0, d1, "processingDelay", "decoded"),
        "assembly_ms": per_frame_ms(d0, d1, "assemblyTime", "assembled"),
        "server_encode_ms_p50": enc.get("encode_ms_p50"),
        "server_encode_ms_p99": enc.get("encode_ms_p99"),
        # The leg's conditions, as applied:
        "browser_session_yields": yielded_session,
        "gpu_threads_niced": gpu_threads,
        "video_nice": int(env.get("TELEROBOT_VIDEO_NICE", "10")),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=60.0, help="of figures, each leg")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=720)
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument(
        "--legs", choices=("both", *LEGS), default="both", help="which legs to run (both)"
    )
    p.add_argument("--dump", help="write each leg's latencies (ms, in order) to this JSON file")
    args = p.parse_args()
    legs = list(LEGS) if args.legs == "both" else [args.legs]
    figures: dict[str, Any] = {}
    for name in legs:
        print(f"leg {name}: {args.seconds:.0f} s", flush=True)
        figures[name] = run_leg(args, LEGS[name])
    if args.dump:
        with open(args.dump, "w") as f:
            json.dump({name: leg["latencies"] for name, leg in figures.items()}, f)
    for leg in figures.values():
        del leg["latencies"]
    for name, leg in figures.items():
        print(f"-- {name}")
        emit(leg, False)
    summary = {
        **figures,
        "width": args.width,
        "height": args.height,
        "busy_core": args.busy_core,
    }
    if "yields" in figures and "equal" in figures:
        # Same run: how much the quick start's p99 is above the tuned leg's.
        summary["p99_ratio_equal_vs_yields"] = (
            figures["equal"]["latency_p99_ms"] / figures["yields"]["latency_p99_ms"]
        )
    if args.json:
        print(json.dumps({**summary, "machine": machine()}))


if __name__ == "__main__":
    main()
