"""Force samples on time while stereo video fills the link. The thesis
saw its force packets go from 0.68 ms mean inter-arrival to 5.4 ms mean and ~20 ms
worst while a stereo frame was on the wire.

    python -m bench.force_under_video [--json] [--seconds 20] [--busy-core]

The server runs on the simulation with the stereo camera at 2×1280×720, 30 fps,
H.264 at a constant 9 Mbit/s (filler data tops a still scene up to the budget, so
the link carries all of it). In a separate client process the master-arm bridge
(simulated master, as an operator) receives every 1 kHz force sample on the priority
channel. One-way latency = receive time − the sample's sensor time: both are the same
machine's CLOCK_MONOTONIC, also across network namespaces. Each run measures without
video, then with an aiortc viewer receiving the video (not decoding it: the link and
the server are under test, not the viewer's CPU).

Links: loopback; and, when run as root, a veth pair between two network namespaces
(bench.netem's NetemPair on its ``lan`` profile: no delay, no loss), the server's side
shaped to 100 Mbit/s by HTB with DSCP EF (the priority channel's mark) in its own class
ahead of the rest, as a DiffServ-aware router would.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import multiprocessing
import os
import secrets
import subprocess
import sys
import time
from typing import Any, Literal

import httpx
import numpy as np

from bench.common import busy_core, emit, machine, open_viewer, parser, serve_for_bench
from bench.netem import NetemPair, netns_available
from telerobot.protocol import messages as m

RATE_MBIT = 100
VIDEO_BITRATE = 9_000_000


# ---------------------------------------------------------------- the client process
def _phase(records: list[tuple[int, float, float]]) -> dict[str, float]:
    seq = np.array([r[0] for r in records], dtype=np.int64)
    latency = np.array([r[2] - r[1] for r in records]) * 1000
    arrivals = np.array([r[2] for r in records])
    gaps = np.diff(arrivals) * 1000
    return {
        "samples": len(records),
        "p50_ms": float(np.percentile(latency, 50)),
        "p99_ms": float(np.percentile(latency, 99)),
        "max_ms": float(latency.max()),
        "interarrival_p50_ms": float(np.percentile(gaps, 50)),
        "interarrival_p99_ms": float(np.percentile(gaps, 99)),
        "interarrival_max_ms": float(gaps.max()),
        "lost": int(seq[-1] - seq[0] + 1 - len(np.unique(seq))),
    }


async def _view(base: str, seconds: float) -> float:
    """A viewer (its own process, as a browser would be) that receives the stereo video
    like a browser, acknowledging RTP, without decoding it. Returns Mbit/s received."""
    import aiortc.rtcrtpreceiver as receiver

    received = [0]
    original = receiver.RTCRtpReceiver._handle_rtp_packet

    async def count(self: Any, packet: Any, arrival_time_ms: int) -> None:
        received[0] += len(packet.payload) + 12  # the RTP header too
        await original(self, packet, arrival_time_ms)

    receiver.RTCRtpReceiver._handle_rtp_packet = count  # type: ignore[method-assign]
    pc, _ = await open_viewer(base)
    await asyncio.sleep(5.0)  # the first keyframe, the rate settles
    b0, t0 = received[0], time.monotonic()
    await asyncio.sleep(seconds)
    mbps = (received[0] - b0) * 8 / (time.monotonic() - t0) / 1e6
    await pc.close()
    return mbps


def ws_listener(base: str, seconds: float, out: Any) -> None:
    """For comparison: the same force samples over /ws (the server's event loop), one
    FORCE message per sample, in a process of its own. Returns (seq, time, received)."""
    from bench.wsclient import RealtimeClient

    async def listen() -> list[tuple[int, float, float]]:
        url = base.replace("http", "ws", 1) + "ws"
        client = await RealtimeClient.connect(url, flags=m.HelloFlags.EVERY_FORCE_SAMPLE)
        records: list[tuple[int, float, float]] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            data = await client.ws.recv()
            now = time.monotonic()
            if data[0] == m.FORCE.type_id:
                records.extend((seq, t, now) for seq, t, _ in m.decode_force(data))
        await client.close()
        return records

    out.put(asyncio.run(listen()))


def viewer(base: str, seconds: float, out: Any) -> None:
    from bench.video import _disable_decoding

    _disable_decoding()
    out.put(asyncio.run(_view(base, seconds)))


def client(base: str, seconds: float, compare_ws: bool = False) -> dict[str, Any]:
    from telerobot.client.master.bridge import BridgeSettings, MasterBridge
    from telerobot.client.master.cli import CPU_PRIORITY, open_link
    from telerobot.drivers.master.sim import SimMaster
    from telerobot.tuning import raise_thread_priority, tune_for_realtime

    tune_for_realtime()  # as `telerobot master` does, and its CPU priority (where allowed)
    raise_thread_priority(int(os.environ.get("BENCH_CLIENT_PRIORITY", CPU_PRIORITY)))
    # The token: forces as datagrams are for operators only (it does not take control).
    link = open_link(base, os.environ.get("BENCH_FORCE_TOKEN", ""))
    bridge = MasterBridge(SimMaster(), link, BridgeSettings())
    records: list[tuple[int, float, float]] = []
    bridge.on_sample = lambda s, at: records.append((s.seq, s.time, at))
    bridge.start(take_control=False)
    ctx = multiprocessing.get_context("spawn")
    ws_out = ctx.Queue()
    ws = ctx.Process(target=ws_listener, args=(base, 2 * seconds + 14, ws_out), daemon=True)
    if compare_ws:
        ws.start()
    time.sleep(2.0)  # connected, past the start-up
    records.clear()
    quiet_window = (time.monotonic(), time.monotonic() + seconds)
    time.sleep(seconds)
    quiet = _phase(list(records))
    out = ctx.Queue()
    view = ctx.Process(target=viewer, args=(base, seconds, out), daemon=True)
    view.start()
    time.sleep(8.0)  # the viewer starts, connects, the first keyframe, the rate settles
    records.clear()
    busy_window = (time.monotonic(), time.monotonic() + seconds)
    time.sleep(seconds)
    busy = _phase(list(records))
    mbps = float(out.get(timeout=60))
    ws_figures = None
    if compare_ws:
        ws_records = ws_out.get(timeout=60)
        ws.join(timeout=10)
        ws_figures = {
            name: _phase([r for r in ws_records if lo <= r[2] <= hi])
            for name, (lo, hi) in (("no_video", quiet_window), ("video", busy_window))
        }
    view.join(timeout=10)
    bridge.stop()
    link.close()
    channel = httpx.get(base + "api/v1/force/channel", timeout=10).json()
    return {"no_video": quiet, "video": busy, "video_mbps": mbps, "ws": ws_figures, **channel}


# ---------------------------------------------------------------- the shaped link
def prioritise_ef(pair: NetemPair) -> None:
    """The server's way out: 100 Mbit/s; EF (forces) in class 1:10 ahead of 1:20 (the
    rest), as a DiffServ-aware router would. The pair stays on the ``lan`` profile, so
    its root qdisc is ours."""
    tc = ["tc", "-n", pair.server_ns]
    dev = ["dev", pair.server_dev]
    rate = f"{RATE_MBIT}mbit"
    for command in (
        ["qdisc", "add", *dev, "root", "handle", "1:", "htb", "default", "20", "r2q", "100"],
        ["class", "add", *dev, "parent", "1:", "classid", "1:1", "htb", "rate", rate],
        ["class", "add", *dev, "parent", "1:1", "classid", "1:10", "htb", "rate", "10mbit",
         "ceil", rate, "prio", "0"],
        ["class", "add", *dev, "parent", "1:1", "classid", "1:20", "htb", "rate", "90mbit",
         "ceil", rate, "prio", "1"],
        ["filter", "add", *dev, "parent", "1:", "protocol", "ip", "prio", "1", "u32",
         "match", "ip", "dsfield", "0xb8", "0xfc", "flowid", "1:10"],
    ):  # fmt: skip
        subprocess.run([*tc, *command], check=True, capture_output=True, text=True)


# ---------------------------------------------------------------- one measurement
def measure(
    seconds: float, netns: NetemPair | Literal[False] | None, compare_ws: bool = False
) -> dict[str, Any]:
    """One run: on loopback when ``netns`` is None or False (bench.recording passes
    False), else the server in the pair's server namespace, the client in its client's."""
    pair = netns or None
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": "1280",
        "TELEROBOT_VIDEO_HEIGHT": "720",
        "TELEROBOT_VIDEO_FPS": "30",
        "TELEROBOT_VIDEO_BITRATE": str(VIDEO_BITRATE),
        "TELEROBOT_VIDEO_CBR": "true",
        "TELEROBOT_OPERATOR_TOKEN": (token := secrets.token_hex(16)),
    }
    host = pair.server_addr if pair else "127.0.0.1"
    server_prefix = pair.server_prefix if pair else ()
    client_prefix = pair.client_prefix if pair else ()
    with serve_for_bench("--host", host, env=env, prefix=server_prefix) as (_, base):
        out = subprocess.run(
            [*client_prefix, sys.executable, "-m", "bench.force_under_video",
             "--client", base, "--seconds", str(seconds),
             *(["--compare-ws"] if compare_ws else [])],
            capture_output=True, text=True, timeout=seconds * 2 + 120,
            env={**os.environ, "BENCH_FORCE_TOKEN": token},
        )  # fmt: skip
        if out.returncode != 0:
            raise RuntimeError(f"the client failed:\n{out.stderr[-3000:]}")
        result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    quiet, busy = result["no_video"], result["video"]
    return {
        "p50_ms_no_video": quiet["p50_ms"],
        "p99_ms_no_video": quiet["p99_ms"],
        "max_ms_no_video": quiet["max_ms"],
        "p50_ms_video": busy["p50_ms"],
        "p99_ms_video": busy["p99_ms"],
        "max_ms_video": busy["max_ms"],
        "interarrival_p50_ms_video": busy["interarrival_p50_ms"],
        "interarrival_p99_ms_video": busy["interarrival_p99_ms"],
        "interarrival_max_ms_video": busy["interarrival_max_ms"],
        "p99_ratio_video_vs_none": busy["p99_ms"] / quiet["p99_ms"],
        "lost": quiet["lost"] + busy["lost"] + result["forces_dropped"],
        "samples": quiet["samples"] + busy["samples"],
        "video_mbps": result["video_mbps"],
        **(
            {
                "ws_p99_ms_no_video": result["ws"]["no_video"]["p99_ms"],
                "ws_p99_ms_video": result["ws"]["video"]["p99_ms"],
                "ws_max_ms_video": result["ws"]["video"]["max_ms"],
            }
            if result.get("ws")
            else {}
        ),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=20.0, help="per phase")
    p.add_argument(
        "--compare-ws",
        action="store_true",
        help="also receive the samples over /ws in another process (for comparison)",
    )
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument("--client", metavar="URL", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.client:
        print(json.dumps(client(args.client, args.seconds, args.compare_ws)))
        return
    with busy_core(args.busy_core):
        figures: dict[str, Any] = {"loopback": measure(args.seconds, False, args.compare_ws)}
        why_not = netns_available()
        if why_not is None:
            with NetemPair("lan") as pair:
                prioritise_ef(pair)
                figures["netns"] = measure(args.seconds, pair, args.compare_ws)
        else:
            figures["netns"] = None
            figures["netns_skipped"] = why_not
    figures["busy_core"] = args.busy_core
    for link in ("loopback", "netns"):
        if figures.get(link):
            print(f"-- {link}")
            emit(figures[link], False)
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
