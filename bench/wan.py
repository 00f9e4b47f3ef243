"""Video, forces and commands over emulated links: each of
harness.netem's profiles (lan, wifi, wan, mobile, bad) with the server in the pair's
server namespace and the clients in its client namespace.

    python -m bench.wan [--json] [--seconds 15] [--profiles mobile,bad] [--viewer browser]

One ``telerobot serve`` (simulation, stereo video at 2×640×360 by default, the
server's own bitrate setting unless ``--video-bitrate``) for all profiles; for each
profile the link is measured (harness.netem.measure_link, probes spaced wider than the
jitter), then three client processes run in the client namespace at once:

* **viewer**: an aiortc peer that decodes every frame and reads the capture time from
  the picture's timecode (drivers/camera/timecode), made to receive as libwebrtc's
  receiver does (harness/wan_receiver.py): RED and ULPFEC undone and lost packets
  rebuilt, a key frame after a gap decoded at once, NACKs for up to 1000 packets
  (``BENCH_WAN_NACK_LIST``), each frame shown on the playout delay the server stamps
  (its time on the fastest frames' schedule plus that delay; the current delay moves
  100 ms a second, as libwebrtc's). Figures at the frame's *shown* time: fps,
  capture → shown p50/p99 (``latency_p50_ms``; ``decoded_latency_p50_ms`` before the
  playout delay; aiortc releases a frame when the next one's first packet arrives, so
  both include up to one frame interval a browser would not wait), frozen share (the
  time inside gaps of > 200 ms without a new frame, whole gaps counted), the longest
  gap, ``playout_delay_ms`` (p50, max over the frames), ``fec_overhead`` (the share of
  the video's bytes to this viewer that were FEC, from the server's figures),
  ``fec_recovered`` (packets the viewer rebuilt).
  ``layer_switches`` comes from the per-viewer entries of GET /api/v1/video: a
  switch counter if the server has one, else the changes of the viewer's ``layer``
  polled once a second; ``layer_switches_source`` says which (and 0 if neither).
  With ``--viewer browser`` the viewer is Debian's Chromium with the operator page
  (observer) instead: frame arrivals from requestVideoFrameCallback, capture →
  decoded from the page's own meter (view/glass.ts); no byte or packet counts. On
  this 2-core machine the browser's software GPU takes most of a core, which the
  server's encoder then lacks: its fps is the machine's, not the link's.
* **force**: the master-arm bridge (simulated master, operator) on the priority
  channel, forces as UDP datagrams (its default; ``force_transport`` says which it
  got): one-way latency = receive time − the sample's sensor time (one machine's
  CLOCK_MONOTONIC, also across namespaces); lost = gaps in the sample numbers (which
  include the samples the bridge asked the server to skip on a lossy link:
  ``force_rate_hz`` says how many came). Beside it, ``link.khz_down_p99_ms``: a bare
  1 kHz UDP stream's one-way p99 through the same link without video, the floor any
  force transport has (a FIFO link holds a stream denser than its jitter behind
  itself).
* **command**: a WebSocket client that takes the lease (take-over) and streams small
  Cartesian increments (``--command-hz``, 50 by default) without waiting for acks, as
  an operator's master arm would. Command latency = ACK's server time − send time
  (one clock, no sync needed). Two ages of an executed command:
  client-side, ``stale_executed`` and ``oldest_executed_ms``: ACK's server time − send
  time over 250 ms (the server's default ``max_command_age_ms``) and the largest; the
  ACK's time is taken after the driver's call returns, so this is the age at the
  acknowledgement and may pass 250 ms by the driver's own time with the command taken
  in time. Server-side, ``executed_age_ms`` (``p50``, ``p99``, ``max``),
  ``executed_server`` (how many) and ``stale_executed_server`` (how many over the
  server's limit): the server's own age of each of this client's executed commands,
  measured on its clock at its last check, the driver's call next (GET
  /api/v1/safety?client=ID, ``executed_age_ms_client``: this profile's client alone,
  since it joined; p50/p99 over its last 4096), the goal ``executed_age_max_le_250ms``.
  The HELLO carries SYNCED_CLOCK when the protocol has it (our client_time is the
  server's clock; without it the server knows no age). Refusals are counted by reason.

Halfway through, the link goes down both ways for ``--outage`` s (1.5 s;
NetemPair.link_down): ``lease_kept`` says the command client held control from the
start to the end, through the outage (the server's lease grace is 2 s). The steady
figures leave out the outage and the second after it (what is still queued after
that second, e.g. a TCP stream waiting for its retransmission timer, stays in);
``before_outage`` has the same figures from the first half alone, and the outage's
own figures (video recovery, the backlog's oldest force) are reported beside them.
``emulator``: what the user-space link emulator itself did in the run (frames its rule
queued > 250 ms, frames it sent late: see ``emulator_figures``).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import itertools
import json
import math
import os
import secrets
import subprocess
import sys
import threading
import time
from typing import Any

import numpy as np

from bench.common import machine, parser
from harness.netem import (
    PROFILES,
    REPO,
    NetemPair,
    emulator_available,
    measure_link,
    probe_interval_s,
)
from harness.servers import serve_for_bench
from telerobot.protocol import messages as m

FREEZE_S = 0.2  # no new frame for longer than this: frozen
STALE_S = 0.25  # the server's default max_command_age_ms
RECOVER_S = 1.0  # left out of the steady figures after the outage
ROLES = ("viewer", "force", "command")
# --viewer: the "viewer" role's process. "aiortc" asks again for a packet whose
# retransmission did not come (libwebrtc's NackRequester: again after a round trip, up
# to 10 times); "aiortc-nack-once" is aiortc's own receiver, which asks once and then
# waits for its 512-packet jitter buffer to overflow before it asks for a key frame.
VIEWERS = ("aiortc", "aiortc-nack-once", "browser")
NACK_RETRIES = 10  # libwebrtc's kMaxNackRetries
NACK_LIST_MAX = 1000  # libwebrtc's kMaxNackPackets


# ---------------------------------------------------------------- client roles
def _stop_event(loop: asyncio.AbstractEventLoop) -> asyncio.Event:
    """An event set when stdin says ``stop`` (or closes)."""
    event = asyncio.Event()

    def wait() -> None:
        sys.stdin.readline()
        loop.call_soon_threadsafe(event.set)

    threading.Thread(target=wait, daemon=True).start()
    return event


def _get_json(base: str, path: str) -> Any:
    import httpx

    try:
        return httpx.get(base + path, timeout=10).json()
    except Exception as exc:  # a figure missing is reported, not fatal
        return {"error": repr(exc)}


def role_viewer(base: str) -> dict[str, Any]:
    import aiortc.rtcrtpreceiver as receiver

    from harness import wan_receiver
    from harness.aiortc_viewers import open_viewer
    from telerobot.drivers.camera import timecode

    rx = wan_receiver.install()  # FEC and the playout delay, as libwebrtc's receiver
    # NACKs for up to 1000 missing packets, as libwebrtc's NackRequester (kMaxNackPackets);
    # aiortc's own stop 128 behind the newest, so after a cut longer than that (FEC's
    # packets make it sooner) the oldest were never asked for, nor a key frame.
    receiver.RTP_HISTORY_SIZE = int(os.environ.get("BENCH_WAN_NACK_LIST", NACK_LIST_MAX))  # type: ignore[attr-defined]
    player = wan_receiver.Playout()
    received = [0]
    packets: list[float] = []  # arrival of every RTP packet (is video still coming?)
    original = receiver.RTCRtpReceiver._handle_rtp_packet

    ssrc: list[int | None] = [None]

    async def count(self: Any, packet: Any, arrival_time_ms: int) -> None:
        received[0] += len(packet.payload) + 12
        ssrc[0] = packet.ssrc
        packets.append(time.monotonic())
        await original(self, packet, arrival_time_ms)

    receiver.RTCRtpReceiver._handle_rtp_packet = count  # type: ignore[method-assign]
    renack_s = float(os.environ.get("BENCH_WAN_RENACK_MS", "0")) / 1000.0
    renacks = [0]

    async def renack(pc: Any) -> None:
        """NACK again what is still missing a round trip after it was last asked for.
        (aiortc's receiver keeps its NackGenerator private: reached by its mangled name.)"""
        rx = pc.getTransceivers()[0].receiver
        nack = rx._RTCRtpReceiver__nack_generator
        asked: dict[int, tuple[float, int]] = {}  # seq → (last asked, times)
        while True:
            await asyncio.sleep(0.02)
            now = time.monotonic()
            missing = set(nack.missing)
            for seq in list(asked):
                if seq not in missing:
                    del asked[seq]
            due = []
            for seq in missing:
                last, times = asked.setdefault(seq, (now, 1))  # aiortc asked once already
                if now - last >= renack_s and times < NACK_RETRIES:
                    asked[seq] = (now, times + 1)
                    due.append(seq)
            if due and ssrc[0] is not None:
                renacks[0] += len(due)
                await rx._send_rtcp_nack(ssrc[0], sorted(due))

    async def run() -> dict[str, Any]:
        stop = _stop_event(asyncio.get_running_loop())
        full_width = (await asyncio.to_thread(_get_json, base, "api/v1/video"))["width"]
        pc, track = await open_viewer(base)
        frames: list[tuple[float, float | None]] = []  # shown, age (None: unreadable)
        decoded: list[tuple[float, float | None]] = []  # the same when decoded
        delays: list[float] = []  # the playout delay each frame was held by (ms)
        last_shown = [0.0]
        bytes_at: list[tuple[float, int]] = []

        async def receive() -> None:
            while True:
                frame = await track.recv()
                now = time.monotonic()
                if not frames:
                    print("ready", flush=True)
                luma = frame.to_ndarray()  # yuv420p: the first `height` rows are Y
                eye = luma[: frame.height, : frame.width // 2]  # the low layer: half size
                code = timecode.read(eye, scale=eye.shape[1] / full_width)
                age = timecode.elapsed(code, now) if code is not None else None
                decoded.append((now, age))
                # Shown at its time on the stream's fastest frames' schedule plus the
                # playout delay the server stamps (0: at once), as libwebrtc does; never
                # before the frame before it. Reckoned, not waited for: a wait here would
                # delay the next frames' decoded times too.
                rtp_s = float(frame.pts * frame.time_base) if frame.pts is not None else 0.0
                shown = max(player.show_at(now, rtp_s, rx.delay_ms / 1000), last_shown[0])
                last_shown[0] = shown
                delays.append(player.delay_s * 1000)
                frames.append((shown, None if age is None else age + shown - now))
                bytes_at.append((now, received[0]))

        polls: list[tuple[float, Any]] = []  # (time, GET /api/v1/video's viewers)

        async def poll() -> None:  # the server's per-viewer layer, once a second
            while True:
                status = await asyncio.to_thread(_get_json, base, "api/v1/video")
                polls.append((time.monotonic(), (status.get("stats") or {}).get("viewers")))
                await asyncio.sleep(1.0)

        task = asyncio.create_task(receive())
        poller = asyncio.create_task(poll())
        tasks = [task, poller]
        buffer = None
        if renack_s > 0:
            tasks.append(asyncio.create_task(renack(pc)))
            # Given up after the retries a round trip apart would have had their chance.
            buffer = wan_receiver.keyframe_skipping_buffer(3 * renack_s)
            pc.getTransceivers()[0].receiver._RTCRtpReceiver__jitter_buffer = buffer
        await stop.wait()
        for t in tasks:
            t.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        status = await asyncio.to_thread(_get_json, base, "api/v1/video")
        await pc.close()
        return {
            "frames": frames,
            "decoded": decoded,
            "playout_delays_ms": delays,
            "fec_received": vars(rx.fec.counts),
            "bytes_at": bytes_at,
            "packets": packets,
            "polls": polls,
            "status": status,
            "renacks": renacks[0],
            "gaps_skipped": None if buffer is None else buffer.skips,
        }

    return asyncio.run(run())


# Injected into the operator page once it shows video: the arrival time of every
# decoded frame (requestVideoFrameCallback on the page's <video>) and every
# capture → decoded figure the page's own glass-to-glass meter adds (view/glass.ts),
# on the page's clock; both bounded (a 20 s run at 30 fps is 600 of each).
PAGE_PROBE = """
(() => {
  const arrivals = (window.__arrivals = []);
  const ages = (window.__ages = []);
  const video = document.getElementById("video");
  const tick = () => {
    if (arrivals.length < 100000) arrivals.push(performance.now());
    video.requestVideoFrameCallback(tick);
  };
  video.requestVideoFrameCallback(tick);
  window.telerobot.glass.listen((v) => {
    if (ages.length < 100000) ages.push([performance.now(), v]);
  });
})()
"""


def role_browser(base: str) -> dict[str, Any]:
    """The viewer as an operator has it: Debian's Chromium with the operator page (as
    an observer: no token), in this (the client's) namespace."""
    from playwright.sync_api import sync_playwright

    from harness.chromium import ARGS, yield_software_gpu

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        # A small window: what is measured is the link, and on this 2-core machine the
        # software GPU's work grows with the pixels it draws (at 1280×720 it took the
        # server's encoder down to 12 fps).
        page = browser.new_page(viewport={"width": 640, "height": 400})
        page.goto(base)
        yield_software_gpu()
        page.wait_for_function(
            "window.telerobot && window.telerobot.view.frames > 10", timeout=60_000, polling=100
        )
        page.evaluate(PAGE_PROBE)
        print("ready", flush=True)
        sys.stdin.readline()
        now_page, arrivals, ages, layer = page.evaluate(
            "[performance.now(), window.__arrivals, window.__ages,"
            " window.telerobot.hud && window.telerobot.hud.rows.find((r) => r.key === 'video')]"
        )
        now = time.monotonic()
        browser.close()
    status = _get_json(base, "api/v1/video")

    def mono(t_page: float) -> float:  # the page's clock → this machine's monotonic one
        return now - (now_page - t_page) / 1000

    return {
        "frames": [(mono(t), None) for t in arrivals],
        "ages": [(mono(t), age / 1000) for t, age in ages],
        "bytes_at": [],
        "packets": [],
        "polls": [],
        "status": status,
        "hud_video_row": layer,
    }


def role_force(base: str, token: str) -> dict[str, Any]:
    from telerobot.client.master.bridge import BridgeSettings, MasterBridge
    from telerobot.client.master.cli import open_link
    from telerobot.drivers.master.sim import SimMaster
    from telerobot.tuning import tune_for_realtime

    tune_for_realtime()
    before = _get_json(base, "api/v1/force/channel")
    link = open_link(base, token)  # (forces as datagrams are for operators only)
    bridge = MasterBridge(SimMaster(), link, BridgeSettings())
    records: list[tuple[int, float, float, int]] = []  # seq, sensor time, received, every
    first = threading.Event()

    def on_sample(s: Any, at: float) -> None:
        records.append((s.seq, s.time, at, link.thinning.every))
        first.set()

    bridge.on_sample = on_sample
    bridge.start(take_control=False)
    first.wait(30)
    print("ready", flush=True)
    sys.stdin.readline()
    bridge.stop()
    link.close()
    after = _get_json(base, "api/v1/force/channel")
    return {
        "records": records,
        "channel_before": before,
        "channel_after": after,
        "transport": link.datagrams,  # "udp" (datagrams), or "tcp: why"
    }


def role_command(base: str, token: str, hz: float) -> dict[str, Any]:
    from harness.wsclient import RealtimeClient, StallResumer

    synced = getattr(m.HelloFlags, "SYNCED_CLOCK", None)

    async def run() -> dict[str, Any]:
        stop = _stop_event(asyncio.get_running_loop())
        url = base.replace("http", "ws", 1) + "ws"
        flags = int(synced or 0) | m.HelloFlags.RESUMABLE  # resumed on a stall, as the page
        op = await RealtimeClient.connect(url, token=token, flags=flags)
        resumer = StallResumer(op, url)
        # Before the lease: pings are no heartbeat, and on ``bad`` 5 of them take ~2.5 s,
        # past the dead-man's 150 ms + 2 s of grace (the offset is for the record only:
        # both ends read one CLOCK_MONOTONIC).
        for attempt in range(3):  # a PONG held > 5 s in a full queue (`bad`): again
            try:
                rtt = await op.sync_clock(rounds=5)
                break
            except TimeoutError:
                if attempt == 2:
                    raise
        await op.ws.send(m.encode(m.LEASE, op.next_seq(), m.LeaseAction.TAKE_OVER))

        async def beat() -> None:
            # The dead-man runs from the take-over, not from its ACK: heartbeats go
            # while the ACK comes down (the page beats from wanting control on). On
            # `bad` the ACK took 0.6–2.4 s, and a silent client lost the lease before
            # the run began in 2 of 17 runs (control_lost_at_s ~0.3, nothing executed).
            while True:
                with contextlib.suppress(Exception):
                    await op.ws.send(m.encode(m.HEARTBEAT, op.next_seq(), time.monotonic()))
                await asyncio.sleep(0.05)

        beating = asyncio.create_task(beat())
        try:
            await op.expect(m.ACK, timeout=15)
        finally:
            beating.cancel()
        sent: dict[int, float] = {}
        acks: dict[int, tuple[float, int, float]] = {}  # seq -> server time, result, received
        errors: dict[int, tuple[int, str, float]] = {}
        control: list[tuple[float, bool]] = []  # STATE: (received, you have control)

        async def read() -> None:
            while True:
                data = await resumer.recv()
                now = time.monotonic()
                kind = data[0]
                if kind == m.ACK.type_id:
                    f = m.decode(data)[1]
                    acks[f["seq"]] = (f["server_time"], f["result"], now)
                elif kind == m.ERROR.type_id:
                    _, f, text = m.decode(data)
                    errors[f["seq"]] = (f["code"], text, now)
                elif kind == m.STATE.type_id:
                    have = bool(m.decode(data)[1]["flags"] & m.StateFlags.YOU_HAVE_CONTROL)
                    if not control or control[-1][1] != have:
                        control.append((now, have))

        reader = asyncio.create_task(read())
        watch = asyncio.create_task(resumer.run())
        print("ready", flush=True)
        period = 1.0 / hz
        next_send = time.monotonic()
        i = 0
        while not stop.is_set():
            dz = 0.0002 if (i // 50) % 2 == 0 else -0.0002  # a small back-and-forth
            seq = op.next_seq()
            now = time.monotonic()
            sent[seq] = now
            with contextlib.suppress(Exception):
                await op.ws.send(
                    m.encode(m.CART_INC, seq, now, m.Frame.BASE, 0.0, 0.0, dz, 0.0, 0.0, 0.0)
                )
            i += 1
            next_send += period
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), max(0.0, next_send - time.monotonic()))
        await asyncio.sleep(1.0)  # the last answers
        for task in (reader, watch):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        # The server's figures, with this client's own executed commands' ages (its
        # id stays the same through resumes; each profile's client is a new one).
        safety = await asyncio.to_thread(_get_json, base, f"api/v1/safety?client={op.client_id}")
        with contextlib.suppress(TimeoutError):  # the close handshake: not worth 10 s
            await asyncio.wait_for(op.close(), 1.0)
        return {
            "sent": sent,
            "acks": acks,
            "errors": errors,
            "control": control,
            "safety": safety,
            "synced_clock_flag": synced is not None,
            "ping_rtt_ms": rtt * 1000,
            "resumed": resumer.resumed,
            "resume_attempts": list(resumer.attempts),
            "clock_offset_ms": op.offset * 1000,
        }

    return asyncio.run(run())


def run_role(role: str, base: str, token: str, hz: float) -> None:
    if role == "viewer":
        out = role_viewer(base)
    elif role == "browser":
        out = role_browser(base)
    elif role == "force":
        out = role_force(base, token)
    else:
        out = role_command(base, token, hz)
    print(json.dumps(out), flush=True)


# ---------------------------------------------------------------- analysis
Segments = list[tuple[float, float]]


def _in(t: float, segments: Segments) -> bool:
    return any(lo <= t <= hi for lo, hi in segments)


def _pct(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _gaps(arrivals: list[float], segments: Segments) -> list[float]:
    """Gaps between new frames inside each segment, its ends counting as frames."""
    gaps: list[float] = []
    for lo, hi in segments:
        points = [lo, *(t for t in arrivals if lo <= t <= hi), hi]
        gaps.extend(b - a for a, b in itertools.pairwise(points))
    return gaps


def video_figures(out: dict[str, Any], segments: Segments, t_up: float) -> dict[str, Any]:
    frames = [(t, age) for t, age in out["frames"]]
    arrivals = [t for t, _ in frames]
    steady = [t for t in arrivals if _in(t, segments)]
    span = sum(hi - lo for lo, hi in segments)
    timed = out.get("ages") or frames  # (the browser's meter reads them apart)
    ages = [age * 1000 for t, age in timed if age is not None and _in(t, segments)]
    gaps = _gaps(arrivals, segments)
    frozen = sum(g for g in gaps if g > FREEZE_S)
    whole = (segments[0][0], segments[-1][1])
    whole_gaps = _gaps(arrivals, [whole])
    after = [t for t in arrivals if t >= t_up]
    nbytes = [(t, b) for t, b in out["bytes_at"] if _in(t, segments)]
    mbps = None
    if len(nbytes) > 1:
        mbps = (nbytes[-1][1] - nbytes[0][1]) * 8 / (nbytes[-1][0] - nbytes[0][0]) / 1e6
    switches, source = layer_switches(out, (segments[0][0], segments[-1][1]))
    viewers = (out.get("status") or {}).get("stats", {}).get("viewers") or []
    decoded = [
        age * 1000 for t, age in out.get("decoded") or [] if age is not None and _in(t, segments)
    ]
    delays = out.get("playout_delays_ms") or []
    server_fec = (viewers[0].get("fec") if viewers else None) or {}
    return {
        "fps": len(steady) / span if span else None,
        "latency_p50_ms": _pct(ages, 50),
        "latency_p99_ms": _pct(ages, 99),
        # Capture → decoded, before the playout delay holds the frame (as shown: above)
        "decoded_latency_p50_ms": _pct(decoded, 50),
        "playout_delay_ms": {"p50": _pct(delays, 50), "max": max(delays) if delays else None},
        # The share of the video's bytes (to this viewer) that were FEC, and what it did
        "fec_overhead": server_fec.get("overhead"),
        "fec_share_at_end": server_fec.get("share"),
        "fec_packets_sent": server_fec.get("fec_packets"),
        "fec_recovered": (out.get("fec_received") or {}).get("recovered"),
        "frozen_share": frozen / span if span else None,
        "longest_freeze_ms": max(gaps) * 1000 if gaps else None,
        "frozen_share_incl_outage": sum(g for g in whole_gaps if g > FREEZE_S)
        / (whole[1] - whole[0]),
        "video_recovery_ms": (after[0] - t_up) * 1000 if after else None,
        "frames_after_outage": len(after),
        "rtp_packets_after_outage": sum(1 for t in out["packets"] if t >= t_up),
        "video_mbps": mbps,
        "nack_retries": out.get("renacks"),
        "gaps_skipped": out.get("gaps_skipped"),
        "frames_unreadable": None
        if "ages" in out
        else sum(1 for t, age in frames if age is None and _in(t, segments)),
        "layer_switches": switches,
        "layer_switches_source": source,
        "server_viewer": viewers[0] if viewers else None,
    }


def layer_switches(out: dict[str, Any], window: tuple[float, float]) -> tuple[int, str]:
    """From GET /api/v1/video's per-viewer entries (one viewer here): a switch counter
    if the server has one, else the changes of ``layer`` polled once a second."""
    viewers = (out.get("status") or {}).get("stats", {}).get("viewers") or []
    counters = sorted(
        k for v in viewers for k, x in v.items()
        if "layer" in k.lower() and "switch" in k.lower() and isinstance(x, int | float)
    )  # fmt: skip
    if counters:
        return int(sum(v.get(counters[0]) or 0 for v in viewers)), (
            f"GET /api/v1/video viewers[].{counters[0]} at the end (whole connection)"
        )
    seen = [
        str(vs[0].get("layer"))
        for t, vs in out.get("polls") or []
        if vs and "layer" in vs[0] and window[0] <= t <= window[1]
    ]
    if not seen:
        return 0, "none: GET /api/v1/video has no per-viewer layer field, so 0"
    changes = sum(1 for a, b in itertools.pairwise(seen) if a != b)
    return changes, (
        f"viewers[].layer polled every 1 s ({len(seen)} polls; layers seen "
        f"{sorted(set(seen))}); no switch counter on the server"
    )


def force_figures(out: dict[str, Any], segments: Segments, t_up: float) -> dict[str, Any]:
    records = out["records"]
    whole = (segments[0][0], segments[-1][1])
    steady = [(r[2] - r[1]) * 1000 for r in records if _in(r[2], segments)]
    run = [r for r in records if whole[0] <= r[2] <= whole[1]]
    seqs = np.unique([r[0] for r in run])
    lost = int(seqs[-1] - seqs[0] + 1 - len(seqs)) if len(seqs) else 0
    seqs_steady = [r[0] for r in records if _in(r[2], segments)]
    lost_steady = 0
    for lo, hi in segments:
        inside = np.unique([r[0] for r in records if lo <= r[2] <= hi])
        lost_steady += int(inside[-1] - inside[0] + 1 - len(inside)) if len(inside) else 0
    backlog = [(r[2] - r[1]) * 1000 for r in records if t_up <= r[2] <= t_up + RECOVER_S]
    # Of those the server sent: with thinning (one in ``every``, the bridge's request
    # when the sample came; older records have no fourth field) a gap holds only the
    # multiples of ``every`` between its two ends.
    sent_lost = 0
    for a, b in itertools.pairwise(sorted(r for r in run if len(r) > 3)):
        every = max(1, int(b[3]))
        sent_lost += max(0, (b[0] - 1) // every - a[0] // every)
    dropped = None
    before, after = out.get("channel_before") or {}, out.get("channel_after") or {}
    if "forces_dropped" in before and "forces_dropped" in after:
        dropped = after["forces_dropped"] - before["forces_dropped"]
    return {
        "force_p50_ms": _pct(steady, 50),
        "force_p99_ms": _pct(steady, 99),
        "force_max_ms": max(steady) if steady else None,
        "force_lost": lost,
        "force_lost_steady": lost_steady,
        "force_lost_of_sent": sent_lost,
        "force_samples": len(run),
        "force_rate_hz": len(seqs_steady) / sum(hi - lo for lo, hi in segments),
        "force_after_outage_max_ms": max(backlog) if backlog else None,
        "server_forces_dropped": dropped,
        "force_transport": out.get("transport"),
    }


def _refusal_kind(text: str) -> str:
    lowered = text.lower()
    for kind in ("stale", "not_allowed", "lease", "e-stop", "force limit", "workspace"):
        if kind in lowered:
            return kind
    return text[:60]


def command_figures(
    out: dict[str, Any], segments: Segments, t_down: float, t_up: float
) -> dict[str, Any]:
    sent = {int(k): v for k, v in out["sent"].items()}
    acks = {int(k): v for k, v in out["acks"].items()}
    errors = {int(k): v for k, v in out["errors"].items()}
    whole = (segments[0][0], segments[-1][1])
    latency = [(acks[s][0] - t) * 1000 for s, t in sent.items() if s in acks and _in(t, segments)]
    in_run = [s for s, t in sent.items() if whole[0] <= t <= whole[1]]
    ages = {s: acks[s][0] - sent[s] for s in sent if s in acks}
    stale_executed = sum(1 for age in ages.values() if age > STALE_S)
    refused: dict[str, int] = {}
    for s in in_run:
        if s in errors:
            kind = _refusal_kind(errors[s][1])
            refused[kind] = refused.get(kind, 0) + 1
    # Control: held from the start (the first STATE after the take-over) to the end.
    control = out["control"]
    lost_at = [t for t, have in control if not have and t >= whole[0]]
    last = control[-1][1] if control else False
    safety = out.get("safety") or {}
    outage = [s for s, t in sent.items() if t_down <= t <= t_up]
    outage_executed = [ages[s] * 1000 for s in outage if s in ages]
    # The server's own age of each of this client's executed commands, at its last
    # check before the driver (GET /safety?client=: this client only, since it joined).
    server_age = safety.get("executed_age_ms_client") or {}
    return {
        "command_p50_ms": _pct(latency, 50),
        "command_p99_ms": _pct(latency, 99),
        "commands_sent": len(in_run),
        "commands_executed": sum(1 for s in in_run if s in acks),
        "commands_refused": refused,
        "commands_unanswered": sum(1 for s in in_run if s not in acks and s not in errors),
        "stale_executed": stale_executed,
        "oldest_executed_ms": max(ages.values()) * 1000 if ages else None,
        "executed_age_ms": (
            {k: server_age.get(k) for k in ("p50", "p99", "max")} if server_age else None
        ),
        "executed_server": server_age.get("count"),
        "stale_executed_server": server_age.get("over_limit"),
        "outage_commands_executed": len(outage_executed),
        "outage_commands_oldest_executed_ms": max(outage_executed) if outage_executed else None,
        "lease_kept": bool(last and not lost_at),
        "sessions_resumed": out.get("resumed", 0),
        "control_lost_at_s": [round(t - whole[0], 3) for t in lost_at],
        "server_stale_commands_dropped": safety.get("stale_commands_dropped"),
        "server_controller_at_end": safety.get("controller"),
        "synced_clock_flag": out["synced_clock_flag"],
        "ping_rtt_ms": out["ping_rtt_ms"],
    }


# ---------------------------------------------------------------- one profile
def _spawn(
    pair: NetemPair,
    role: str,
    base: str,
    token: str,
    hz: float,
    viewer: str = "aiortc",
    rtt_ms: float = 100.0,
) -> subprocess.Popen[str]:
    process = "browser" if role == "viewer" and viewer == "browser" else role
    # Asked again 1.5 round trips after the last ask (the link's jitter on top).
    renack_ms = 1.5 * max(rtt_ms, 10.0) if viewer == "aiortc" else 0.0
    return subprocess.Popen(
        [*pair.client_prefix, sys.executable, "-m", "bench.wan", "--role", process,
         "--base", base, "--command-hz", str(hz)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "BENCH_WAN_TOKEN": token, "BENCH_WAN_RENACK_MS": str(renack_ms)},
        cwd=REPO,
    )  # fmt: skip


def _collect(proc: subprocess.Popen[str], role: str) -> dict[str, Any]:
    try:
        out, err = proc.communicate("stop\n", timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    lines = [ln for ln in out.splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"the {role} client failed ({proc.returncode}):\n{err[-3000:]}")
    result: dict[str, Any] = json.loads(lines[-1])
    return result


def run_profile(
    pair: NetemPair,
    base: str,
    token: str,
    seconds: float,
    outage_s: float,
    hz: float,
    viewer: str = "aiortc",
    rtt_ms: float = 100.0,
) -> dict[str, Any]:
    procs = {role: _spawn(pair, role, base, token, hz, viewer, rtt_ms) for role in ROLES}
    try:
        deadline = time.monotonic() + 60
        for role, proc in procs.items():
            assert proc.stdout is not None
            while (line := proc.stdout.readline()) and line.strip() != "ready":
                pass
            if not line or time.monotonic() > deadline:
                why = proc.stderr.read()[-3000:] if proc.stderr else ""
                raise RuntimeError(f"the {role} client did not start: {why}")
        time.sleep(1.0)  # the rate settles after the first keyframe
        t_start = time.monotonic()
        time.sleep(seconds / 2)
        t_down = time.monotonic()
        pair.link_down(outage_s)
        t_up = time.monotonic()
        time.sleep(max(0.0, t_start + seconds + outage_s - time.monotonic()))
        t_end = time.monotonic()
        results = {role: _collect(proc, role) for role, proc in procs.items()}
        if dump := os.environ.get("BENCH_WAN_DUMP"):  # raw records, for a closer look
            with open(dump, "w") as f:
                json.dump({"times": [t_start, t_down, t_up, t_end], **results}, f)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    segments = [(t_start, t_down), (t_up + RECOVER_S, t_end)]
    before = [(t_start, t_down)]  # the link as it is, no outage backlog yet
    early = {
        **video_figures(results["viewer"], before, t_up),
        **force_figures(results["force"], before, t_up),
        **command_figures(results["command"], before, t_down, t_up),
    }
    keys = (
        "fps", "latency_p50_ms", "latency_p99_ms", "frozen_share", "longest_freeze_ms",
        "force_p50_ms", "force_p99_ms", "force_lost", "command_p50_ms", "command_p99_ms",
    )  # fmt: skip
    return {
        "before_outage": {k: early[k] for k in keys},
        **video_figures(results["viewer"], segments, t_up),
        **force_figures(results["force"], segments, t_up),
        **command_figures(results["command"], segments, t_down, t_up),
        "steady_s": sum(hi - lo for lo, hi in segments),
        "outage_s": t_up - t_down,
    }


def emulator_figures(before: Any, after: Any) -> dict[str, Any]:
    """What the user-space forwarder did during one profile's run, per direction: frames
    in / lost / out, those its rule queued for > 250 ms (the link's own queue) and those
    it sent more than 5 ms late (CPU the machine did not give it: the machine's share
    of a figure, not the link's), and ``late_max_us``, the largest lateness since the
    emulator started. Empty with the netem backend."""
    if not before or not after:
        return {}
    figures: dict[str, Any] = {}
    for direction, counts in after.items():
        was = before.get(direction, {})
        figures[direction] = {
            k: v if k.endswith("_max_us") else v - was.get(k, 0) for k, v in counts.items()
        }
    return figures


def dense_figures(dense: Any) -> dict[str, Any]:
    """One-way figures of a 1 kHz UDP stream, server → client (the forces' direction)."""
    down = [(r - e) * 1000 for _, e, r in dense.answered.values()]
    return {
        "khz_down_p50_ms": _pct(down, 50),
        "khz_down_p99_ms": _pct(down, 99),
        "khz_loss_down": dense.loss_down,
    }


def goals(name: str, row: dict[str, Any]) -> dict[str, Any]:
    """The goals beside the figures (docs/PERFORMANCE.md; reported, never enforced)."""
    out: dict[str, Any] = {"no_stale_executed": row["stale_executed"] == 0}
    # The server's age at execution (False when the server gave none).
    oldest = (row.get("executed_age_ms") or {}).get("max")
    out["executed_age_max_le_250ms"] = oldest is not None and oldest <= STALE_S * 1000
    out["lease_kept_through_outage"] = row["lease_kept"]
    one_way = row["link"]["down_p50_ms"]
    if name in ("lan", "wifi") or (row.get("fec_overhead") or 0) == 0:
        out["fec_overhead"] = row.get("fec_overhead")
    if name == "mobile":
        out["fps_ge_25"] = (row["fps"] or 0) >= 25
        out["frozen_le_2pct"] = row["frozen_share"] is not None and row["frozen_share"] <= 0.02
        out["longest_freeze_le_300ms"] = (row["longest_freeze_ms"] or math.inf) <= 300
        out["force_p99_le_one_way_plus_5ms"] = (
            row["force_p99_ms"] is not None and row["force_p99_ms"] <= one_way + 5
        )
        out["force_p99_budget_ms"] = one_way + 5
        # The same against the link's own p99 for a 1 kHz stream (dense_figures).
        floor = row["link"].get("khz_down_p99_ms")
        if floor is not None and row["force_p99_ms"] is not None:
            out["force_p99_le_khz_udp_p99_plus_5ms"] = row["force_p99_ms"] <= floor + 5
            out["force_p99_minus_khz_udp_p99_ms"] = row["force_p99_ms"] - floor
    if name == "bad":
        out["no_stall_over_1s"] = (row["longest_freeze_ms"] or math.inf) <= 1000
        out["longest_freeze_le_500ms"] = (row["longest_freeze_ms"] or math.inf) <= 500
        out["longest_freeze_ms"] = row["longest_freeze_ms"]
    return out


# ---------------------------------------------------------------- main
def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=15.0, help="per profile (plus the outage)")
    p.add_argument("--profiles", default=",".join(PROFILES), help="comma-separated subset")
    p.add_argument("--outage", type=float, default=1.5, help="seconds the link is down, mid-run")
    p.add_argument("--width", type=int, default=640, help="of one eye")
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--video-bitrate", type=int, help="default: the server's own setting")
    p.add_argument("--command-hz", type=float, default=50.0)
    p.add_argument(
        "--pacing", action="store_true", help="the video's packets paced (off by default)"
    )
    p.add_argument("--probes", type=int, default=60, help="link probes per profile")
    p.add_argument(
        "--viewer",
        choices=VIEWERS,
        default="aiortc",
        help="who watches: an aiortc peer that decodes in Python, or Debian's Chromium"
        " with the operator page (what an operator has; heavier on this machine)",
    )
    p.add_argument("--role", choices=(*ROLES, "browser"), help=argparse.SUPPRESS)
    p.add_argument("--base", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role:
        run_role(args.role, args.base, os.environ.get("BENCH_WAN_TOKEN", ""), args.command_hz)
        return
    names = [n.strip() for n in args.profiles.split(",") if n.strip()]
    unknown = [n for n in names if n not in PROFILES]
    if unknown:
        p.error(f"unknown profiles {unknown}; there are {list(PROFILES)}")
    if (why := emulator_available()) is not None:
        print(f"no link emulator here: {why}", file=sys.stderr)
        if args.json:
            print(json.dumps({"skipped": why, "machine": machine()}))
        return
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": str(args.width),
        "TELEROBOT_VIDEO_HEIGHT": str(args.height),
        "TELEROBOT_VIDEO_FPS": "30",
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_HOME_POSE": "qn",
        **({"TELEROBOT_VIDEO_BITRATE": str(args.video_bitrate)} if args.video_bitrate else {}),
        **({"TELEROBOT_VIDEO_PACING": "true"} if args.pacing else {}),
    }
    figures: dict[str, Any] = {}
    started = time.monotonic()
    with (
        NetemPair("lan") as pair,
        serve_for_bench("--host", pair.server_addr, env=env, prefix=pair.server_prefix) as (
            _,
            base,
        ),
    ):
        ready_at = time.monotonic() + 5.0  # the simulated arm initialises (qz → qn)
        for name in names:
            profile = PROFILES[name]
            pair.apply(profile)
            link = measure_link(pair, probes=args.probes, interval_s=probe_interval_s(profile))
            # The same link under a 1 kHz stream (as the forces): a FIFO link holds
            # packets closer than its jitter behind each other, so this stream's own
            # one-way delay is the floor for any force transport.
            dense = measure_link(pair, probes=2000, interval_s=0.001)
            time.sleep(max(0.0, ready_at - time.monotonic()))
            counted = pair.forwarder_counters()
            row = run_profile(
                pair,
                base,
                token,
                args.seconds,
                args.outage,
                args.command_hz,
                args.viewer,
                rtt_ms=float(link.figures().get("rtt_p50_ms") or 100.0),
            )
            row["viewer"] = args.viewer
            row["emulator"] = emulator_figures(counted, pair.forwarder_counters())
            row["link"] = {
                "profile": name,
                "backend": pair.backend or "none",
                **link.figures(),
                **dense_figures(dense),
            }
            row["goals"] = goals(name, row)
            figures[name] = row
            print(f"-- {name}: {profile}")
            for k, v in row.items():
                if not isinstance(v, dict | list):
                    print(f"  {k:<36} {v:.4g}" if isinstance(v, float) else f"  {k:<36} {v}")
            print(f"  goals {row['goals']}", flush=True)
    summary = {
        "video": {
            "width_per_eye": args.width,
            "height": args.height,
            "fps": 30,
            "bitrate": args.video_bitrate or "server default (TELEROBOT_VIDEO_BITRATE unset)",
        },
        "command_hz": args.command_hz,
        "video_pacing": args.pacing,
        "seconds": args.seconds,
        "outage_s": args.outage,
        "wall_s": time.monotonic() - started,
        "machine": machine(),
    }
    print(f"wall time {summary['wall_s']:.0f} s")
    if args.json:
        print(json.dumps({**figures, **summary}))


if __name__ == "__main__":
    main()
