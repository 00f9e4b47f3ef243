"""Force samples on time while stereo video fills the link. The thesis
saw its force packets go from 0.68 ms mean inter-arrival to 5.4 ms mean and ~20 ms
worst while a stereo frame was on the wire.

    python -m bench.force_under_video [--json] [--seconds 20] [--busy-core] [--unprivileged]
                                      [--fps 60 [--vs-30]]

``--fps`` (issue 56): the server's video rate (TELEROBOT_VIDEO_FPS, 30 by default), held
whatever the machine does (TELEROBOT_VIDEO_FPS_AUTO=false: the forces measured under
that rate's load); the JSON says it (``fps``) and what the server made of it at the end
of each loopback run
(``server_video``: ``fps_target``, ``fps_why``, ``capture_fps``, ``encode_ms_p50``/
``_p99``, ``frames_encoded``, the frame-rate rule's figures: backend/media/frame_rate.py).
``--vs-30``: the loopback run again at 30 fps right after, under ``at_30`` (its usual
keys), and ``p99_ratio_vs_30``: the p99 under video at ``--fps`` over that at 30.

``--unprivileged`` (issue 51): the loopback run again with the server and the client as
nobody (``setpriv``, no capabilities: the 1 kHz threads ordinary, in short slices, and no
raised priority), under ``unprivileged`` {"loopback": {"p99_ms_video", "p99_ms_none",
"lost", …}, "euid", "force_threads", "p99_ratio_vs_privileged"}. Every run's
``force_threads`` says what the server's 1 kHz threads got (GET /api/v1/health), and
``machine.euid`` who ran the bench.

The server runs on the simulation with the stereo camera at 2×1280×720, 30 fps (``--fps``),
H.264 at a constant 9 Mbit/s (filler data tops a still scene up to the budget, so
the link carries all of it). In a separate client process the master-arm bridge
(simulated master, as an operator) receives every 1 kHz force sample on the priority
channel. One-way latency = receive time − the sample's sensor time: both are the same
machine's CLOCK_MONOTONIC, also across network namespaces. Each run measures without
video, then with an aiortc viewer receiving the video (not decoding it: the link and
the server are under test, not the viewer's CPU).

``--tcp``: the forces on the channel's TCP socket (the bridge asks for datagrams).

``--arms 2`` (issue 33): per link, a server of one ``--arms-model`` arm (the one
stream), then one of two (``TELEROBOT_ARMS=left=…,right=…``: two sensors, two 1 kHz
streams on the one priority channel, each FORCE naming its arm) measured the same way,
``--rounds`` times alternated (ABBA). The bridge's link hands every arm's samples over
(``on_arm_force``); each stream's one-way latency and losses are its own. The one-arm
server's figures are then the usual keys; the JSON adds ``p99_ms_per_arm_under_video``,
``p99_ratio_two_vs_one`` (the worse stream's p99 under video over the one stream's,
medians over the rounds) and ``lost_per_arm``, each by link, and ``arms`` (the details).

Links: loopback; and, when run as root, a veth pair between two network namespaces
(harness.netem's NetemPair on its ``lan`` profile: no delay, no loss), the server's side
shaped to 100 Mbit/s by HTB with DSCP EF (the priority channel's mark) in its own class
ahead of the rest, as a DiffServ-aware router would.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import math
import multiprocessing
import os
import secrets
import shutil
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from typing import Any, Literal

import httpx
import numpy as np

from bench.common import arm_names, arms_env, busy_core, emit, machine, parser
from harness.aiortc_viewers import open_viewer
from harness.netem import NetemPair, netns_available
from harness.servers import SERVER_SCHEDULING, UNPRIVILEGED_UID, as_user, serve_for_bench
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
    from harness.wsclient import RealtimeClient

    async def listen() -> list[tuple[int, float, float]]:
        url = base.replace("http", "ws", 1) + "ws"
        client = await RealtimeClient.connect(url, flags=m.HelloFlags.EVERY_FORCE_SAMPLE)
        records: list[tuple[int, float, float]] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            data = await client.ws.recv()
            now = time.monotonic()
            if data[0] == m.FORCE.type_id and m.force_arm(data) == 1:  # the first arm's
                records.extend((seq, t, now) for seq, t, _ in m.decode_force(data))
        await client.close()
        return records

    out.put(asyncio.run(listen()))


def viewer(base: str, seconds: float, out: Any) -> None:
    from bench.video import _disable_decoding

    _disable_decoding()
    out.put(asyncio.run(_view(base, seconds)))


def client(
    base: str, seconds: float, compare_ws: bool = False, arms: int = 1, tcp: bool = False
) -> dict[str, Any]:
    from telerobot.client.master.bridge import BridgeSettings, MasterBridge
    from telerobot.client.master.cli import CPU_PRIORITY, open_link
    from telerobot.drivers.master.sim import SimMaster
    from telerobot.tuning import raise_thread_priority, tune_for_realtime

    tune_for_realtime()  # as `telerobot master` does, and its CPU priority (where allowed)
    raise_thread_priority(int(os.environ.get("BENCH_CLIENT_PRIORITY", CPU_PRIORITY)))
    # The token: forces as datagrams are for operators only (it does not take control).
    link = open_link(base, os.environ.get("BENCH_FORCE_TOKEN", ""), datagrams=not tcp)
    bridge = MasterBridge(SimMaster(), link, BridgeSettings())
    records: list[tuple[int, float, float]] = []
    by_arm: dict[int, list[tuple[int, float, float]]] = defaultdict(list)
    if arms == 1:
        bridge.on_sample = lambda s, at: records.append((s.seq, s.time, at))
    else:  # every arm's stream, each by itself (both stamped at the same socket read)
        link.on_arm_force = lambda arm, s, at: by_arm[arm].append((s.seq, s.time, at))
    bridge.start(take_control=False)
    ctx = multiprocessing.get_context("spawn")
    ws_out = ctx.Queue()
    ws = ctx.Process(target=ws_listener, args=(base, 2 * seconds + 14, ws_out), daemon=True)
    if compare_ws:
        ws.start()
    time.sleep(2.0)  # connected, past the start-up
    records.clear()
    by_arm.clear()
    quiet_window = (time.monotonic(), time.monotonic() + seconds)
    time.sleep(seconds)
    quiet = _phase(list(records)) if arms == 1 else None
    quiet_by_arm = {arm: _phase(list(r)) for arm, r in sorted(by_arm.items())}
    out = ctx.Queue()
    view = ctx.Process(target=viewer, args=(base, seconds, out), daemon=True)
    view.start()
    time.sleep(8.0)  # the viewer starts, connects, the first keyframe, the rate settles
    records.clear()
    by_arm.clear()
    busy_window = (time.monotonic(), time.monotonic() + seconds)
    time.sleep(seconds)
    busy = _phase(list(records)) if arms == 1 else None
    busy_by_arm = {arm: _phase(list(r)) for arm, r in sorted(by_arm.items())}
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
    if arms > 1:  # the first arm's under the usual keys; every arm's by its index
        if 1 not in quiet_by_arm or 1 not in busy_by_arm:
            raise RuntimeError(f"no sample of the first arm came (arms heard: {list(by_arm)})")
        quiet, busy = quiet_by_arm[1], busy_by_arm[1]
    return {
        "no_video": quiet,
        "video": busy,
        "video_mbps": mbps,
        "ws": ws_figures,
        "per_arm": {"no_video": quiet_by_arm, "video": busy_by_arm} if arms > 1 else None,
        **channel,
    }


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
    seconds: float,
    netns: NetemPair | Literal[False] | None,
    compare_ws: bool = False,
    arms: int = 1,
    arms_model: str | None = None,
    tcp: bool = False,
    user: int | None = None,
    fps: float = 30.0,
) -> dict[str, Any]:
    """One run: on loopback when ``netns`` is None or False (bench.recording passes
    False), else the server in the pair's server namespace, the client in its client's.
    With ``arms_model``: a server of ``arms`` arms of that model (else the default one);
    with two or more, each arm's stream by itself too (``*_per_arm``). ``tcp``: the
    forces on the channel's TCP socket (else as datagrams, as the bridge asks). ``user``:
    the server and the client run as that user, with no rights (``--unprivileged``)."""
    pair = netns or None
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": "1280",
        "TELEROBOT_VIDEO_HEIGHT": "720",
        "TELEROBOT_VIDEO_FPS": f"{fps:g}",
        # The rate held (the forces measured under that rate's load, not under 30 after
        # the server dropped to it): server_video says how the encoder fared.
        "TELEROBOT_VIDEO_FPS_AUTO": "false",
        "TELEROBOT_VIDEO_BITRATE": str(VIDEO_BITRATE),
        "TELEROBOT_VIDEO_CBR": "true",
        "TELEROBOT_OPERATOR_TOKEN": (token := secrets.token_hex(16)),
        **(arms_env(arms, arms_model) if arms_model else {}),
    }
    host = pair.server_addr if pair else "127.0.0.1"
    server_prefix = pair.server_prefix if pair else ()
    client_prefix = (*(pair.client_prefix if pair else ()), *as_user(user))
    with serve_for_bench("--host", host, env=env, prefix=server_prefix, user=user) as (_, base):
        out = subprocess.run(
            [*client_prefix, sys.executable, "-m", "bench.force_under_video",
             "--client", base, "--seconds", str(seconds), "--arms", str(arms),
             *(["--compare-ws"] if compare_ws else []), *(["--tcp"] if tcp else [])],
            capture_output=True, text=True, timeout=seconds * 2 + 120,
            env={**os.environ, "BENCH_FORCE_TOKEN": token},
        )  # fmt: skip
        if out.returncode != 0:
            raise RuntimeError(f"the client failed:\n{out.stderr[-3000:]}")
        result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
        server_video = video_stats(base, token)
    quiet, busy = result["no_video"], result["video"]
    figures = {
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
        "force_threads": dict(SERVER_SCHEDULING),
        "fps": fps,
        "server_video": server_video,
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
    if result.get("per_arm"):
        figures.update(per_arm_figures(result, arms))
    return figures


VIDEO_KEYS = (
    "fps_target", "fps_configured", "fps_why", "fps_rule", "capture_fps", "encode_ms_p50",
    "encode_ms_p99", "frames_encoded",
)  # fmt: skip


def video_stats(base: str, token: str) -> dict[str, Any] | None:
    """What the server made of its video rate by the end of the run (None: no answer)."""
    try:
        r = httpx.get(
            base.rstrip("/") + "/api/v1/video", headers={"Authorization": f"Bearer {token}"}
        )
        stats = r.json().get("stats") or {}
    except (httpx.HTTPError, ValueError):
        return None
    return {k: stats.get(k) for k in VIDEO_KEYS}


def unprivileged(seconds: float, tcp: bool, privileged: dict[str, Any]) -> dict[str, Any]:
    """The loopback run again with the server and the client as nobody (what a laptop
    user, a plain service or Docker's default capabilities get: no realtime, no raised
    priority), beside the privileged run of the same invocation."""
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        return {"skipped": "needs root (to become nobody) and util-linux's setpriv"}
    # The server spawns its media worker and the client its viewer: nobody must be able
    # to start this interpreter itself (a venv whose Python lives under /root cannot).
    starts_itself = "import subprocess as s, sys; s.run([sys.executable, '-c', '0'], check=True)"
    probe = [*as_user(UNPRIVILEGED_UID), sys.executable, "-c", starts_itself]
    if subprocess.run(probe, capture_output=True, timeout=60).returncode != 0:
        return {
            "skipped": f"nobody cannot start {sys.executable} (it lives where a plain user"
            " cannot reach, e.g. under /root): run the bench from an installation a plain"
            " user can read"
        }
    run = measure(seconds, False, tcp=tcp, user=UNPRIVILEGED_UID)
    return {
        "loopback": {
            "p99_ms_video": run["p99_ms_video"],
            "p99_ms_none": run["p99_ms_no_video"],
            "p50_ms_video": run["p50_ms_video"],
            "max_ms_video": run["max_ms_video"],
            "lost": run["lost"],
            "p99_ratio_video_vs_none": run["p99_ratio_video_vs_none"],
        },
        "euid": UNPRIVILEGED_UID,
        "force_threads": run["force_threads"],
        # Same run: the unprivileged p99 under video over the privileged one's.
        "p99_ratio_vs_privileged": run["p99_ms_video"] / privileged["p99_ms_video"],
    }


def per_arm_figures(result: dict[str, Any], arms: int) -> dict[str, Any]:
    """Each arm's stream by the arm's name: p50/p99/max with video and p99 without,
    samples and sequence gaps (None: nothing came of it); and what the channel did not
    send (forces dropped for a slow client, datagrams past a client's rate: the
    channel's counts, every arm's)."""
    names = arm_names(arms)
    # by the arm's index, as JSON keys: "1", "2"
    quiet: dict[str, dict[str, Any]] = result["per_arm"]["no_video"]
    busy: dict[str, dict[str, Any]] = result["per_arm"]["video"]

    def each(phase: dict[str, dict[str, Any]], key: str) -> dict[str, Any]:
        return {name: phase.get(str(i + 1), {}).get(key) for i, name in enumerate(names)}

    def both(key: str) -> dict[str, Any]:
        q, b = each(quiet, key), each(busy, key)
        return {n: None if q[n] is None or b[n] is None else q[n] + b[n] for n in names}

    return {
        "p50_ms_per_arm_under_video": each(busy, "p50_ms"),
        "p99_ms_per_arm_under_video": each(busy, "p99_ms"),
        "max_ms_per_arm_under_video": each(busy, "max_ms"),
        "interarrival_p99_ms_per_arm_under_video": each(busy, "interarrival_p99_ms"),
        "p99_ms_per_arm_no_video": each(quiet, "p99_ms"),
        "samples_per_arm": both("samples"),
        "lost_per_arm": both("lost"),
        "channel_forces_dropped": result["forces_dropped"],
        "datagrams_over_rate": result.get("limits", {}).get("datagrams_over_rate"),
    }


def compare_arms(
    seconds: float,
    netns: NetemPair | Literal[False] | None,
    arms: int,
    model: str,
    rounds: int,
    tcp: bool = False,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """A one-arm server (one stream) and one of ``arms`` arms, ``rounds`` times
    alternated (ABBA): the one-arm run with the median p99 under video (the usual keys),
    and the arms' figures with ``p99_ratio_two_vs_one``: the median over the rounds of
    the worse stream's p99 under video over the median of the one stream's."""
    one: list[dict[str, Any]] = []
    many: list[dict[str, Any]] = []
    for r in range(rounds):
        for n in (1, arms) if r % 2 == 0 else (arms, 1):
            (one if n == 1 else many).append(measure(seconds, netns, False, n, model, tcp))
    names = arm_names(arms)
    # A stream of which nothing came counts as infinitely late (the JSON says None).
    p99s = {n: [f["p99_ms_per_arm_under_video"][n] or math.inf for f in many] for n in names}
    one_p99 = [f["p99_ms_video"] for f in one]
    worst_p99 = [max(run) for run in zip(*p99s.values(), strict=True)]
    middle = one_p99.index(statistics.median_low(one_p99))

    def finite(x: float) -> float | None:
        return x if math.isfinite(x) else None

    arms_figures = {
        "p99_ms_per_arm_under_video": {n: finite(statistics.median(v)) for n, v in p99s.items()},
        "p99_ms_one_arm_under_video": statistics.median(one_p99),
        "p99_ratio_two_vs_one": finite(statistics.median(worst_p99) / statistics.median(one_p99)),
        "lost_per_arm": {  # None: a stream of which nothing came in some run
            n: None if None in (lost := [f["lost_per_arm"][n] for f in many]) else sum(lost)
            for n in names
        },
        "lost_one_arm": sum(f["lost"] for f in one),
        "rounds": [
            {"one_arm_p99_ms_video": o, "worst_arm_p99_ms_video": finite(w), "ratio": finite(w / o)}
            for o, w in zip(one_p99, worst_p99, strict=True)
        ],
        "runs": many,
    }
    return one[middle], arms_figures


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=20.0, help="per phase")
    p.add_argument(
        "--compare-ws",
        action="store_true",
        help="also receive the samples over /ws in another process (for comparison)",
    )
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument(
        "--arms", type=int, default=1, help="2: one stream against two (issue 33), per link"
    )
    p.add_argument("--arms-model", default="so101", help="every arm's model (--arms)")
    p.add_argument(
        "--rounds", type=int, default=1, help="one-arm / two-arm servers alternated (--arms)"
    )
    p.add_argument(
        "--tcp", action="store_true", help="forces on the channel's TCP socket, not datagrams"
    )
    p.add_argument(
        "--unprivileged",
        action="store_true",
        help="also run the server and the client as nobody (no rights: the forces' threads"
        " ordinary), on loopback, after the privileged run",
    )
    p.add_argument(
        "--fps", type=float, default=30.0, help="the server's video rate (TELEROBOT_VIDEO_FPS)"
    )
    p.add_argument(
        "--vs-30",
        action="store_true",
        help="with --fps: the loopback run again at 30 fps right after, for a same-run ratio",
    )
    p.add_argument("--client", metavar="URL", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.client:
        print(json.dumps(client(args.client, args.seconds, args.compare_ws, args.arms, args.tcp)))
        return
    arms: dict[str, Any] = {}  # by link, with --arms

    def one_link(link: str, netns: NetemPair | Literal[False]) -> dict[str, Any]:
        if args.arms == 1:
            return measure(args.seconds, netns, args.compare_ws, tcp=args.tcp, fps=args.fps)
        one, arms[link] = compare_arms(
            args.seconds, netns, args.arms, args.arms_model, args.rounds, args.tcp
        )
        return one

    with busy_core(args.busy_core):
        figures: dict[str, Any] = {"loopback": one_link("loopback", False)}
        why_not = netns_available()
        if why_not is None:
            with NetemPair("lan") as pair:
                prioritise_ef(pair)
                figures["netns"] = one_link("netns", pair)
        else:
            figures["netns"] = None
            figures["netns_skipped"] = why_not
        if args.vs_30 and args.arms == 1:
            at_30 = measure(args.seconds, False, args.compare_ws, tcp=args.tcp, fps=30.0)
            figures["at_30"] = at_30
            figures["p99_ratio_vs_30"] = figures["loopback"]["p99_ms_video"] / at_30["p99_ms_video"]
        if args.unprivileged:
            figures["unprivileged"] = unprivileged(args.seconds, args.tcp, figures["loopback"])
    figures["busy_core"] = args.busy_core
    figures["fps"] = args.fps
    figures["forces_on"] = "tcp" if args.tcp else "datagrams"
    if arms:
        for key in ("p99_ms_per_arm_under_video", "p99_ratio_two_vs_one", "lost_per_arm"):
            figures[key] = {name: a[key] for name, a in arms.items()}
        figures["arms"] = {"arms": args.arms, "model": args.arms_model, **arms}
    for link in ("loopback", "netns"):
        if figures.get(link):
            print(f"-- {link}")
            emit(figures[link], False)
        if link in arms:
            print(f"-- {link}, {args.arms} arms ({args.arms_model}), each stream:")
            emit({k: v for k, v in arms[link].items() if k != "runs"}, False)
            for key in ("p99_ms_per_arm_under_video", "lost_per_arm"):
                print(f"{key}: {arms[link][key]}")
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
