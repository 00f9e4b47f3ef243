"""Video, forces and commands over emulated links: each of
harness.netem's profiles (lan, wifi, wan, mobile, bad) with the server in the pair's
server namespace and the clients in its client namespace.

    python -m bench.wan [--json] [--seconds 15] [--profiles mobile,bad]
                        [--viewer both|aiortc|browser] [--observer-viewer]

One ``telerobot serve`` (simulation, stereo video at 2×640×360 by default, the
server's own bitrate setting unless ``--video-bitrate``) for all profiles; for each
profile the link is measured (harness.netem.measure_link, probes spaced wider than the
jitter), then two legs run one after the other on that link (``--viewer both``, the
default; ``--viewer aiortc`` or ``browser`` runs one): first a **Chromium leg**, then
a **modelled-viewer leg**, each three client processes in the client namespace at
once (a viewer, the force client, the command client), each with its own outage.
The profile's row is the modelled leg's figures (the keys below), with ``chromium``
(the Chromium leg's viewer figures, and its force and command figures in brief),
``lease_kept`` true only if the command client kept the lease in both legs and
``lease_kept_by_leg`` (``chromium``, ``modelled``), ``emulator`` per leg, and
``profile_wall_s``. With ``--viewer browser`` alone the row's video keys are
Chromium's (``latency_*``: capture → shown) and ``chromium`` is there too.

Both viewers are the operator's (``--observer-viewer``: tokenless, an observer's, as
before): the aiortc viewer's POST /api/v1/webrtc/offer carries ``Authorization:
Bearer <token>`` (the server's TELEROBOT_OPERATOR_TOKEN), the page is opened with
``?token=<token>`` as an operator opens it (web/src/api.ts readToken; its REST
requests, the video offer among them, carry it). The page does not take the lease by
itself (only its Take button, the retake offer after it lost control, or the dead-man
while a policy drives do; none is pressed): the command client holds it, and the
probe polls the page's STATE flag YOU_HAVE_CONTROL (``chromium.page_held_lease``).
Each viewer closes its server peer on leaving (DELETE, as the page does on pagehide: a
peer left to ICE's timeout is sent video for half a minute, into the next leg), and
its server figures (``server_viewer``, ``layer_switches``) are its own entry in GET
/api/v1/video, found by its peer id (read with the operator token).

* **Chromium viewer** (``chromium``): Debian's /usr/bin/chromium through Playwright
  (never a downloaded browser) with the operator page, a 640×400 window, its software
  GPU (SwiftShader) at nice 10 (harness/chromium.py). Measured per frame the page
  shows, by requestVideoFrameCallback on the page's <video> (the page draws its WebGL
  view in the same callbacks, view/stereo.ts; PAGE_PROBE): *shown* is the callback's
  ``expectedDisplayTime``; the *capture* time is the timecode read off that very frame
  (``new VideoFrame(video)`` in the callback, the 2-row strip and threshold
  view/glass.ts reads), the server's CLOCK_MONOTONIC at capture. The page's clock
  (performance.now(), Chromium's CLOCK_MONOTONIC from the page's start) is mapped onto
  this machine's by the tightest of 30 (before, performance.now(), after) reads (15 as
  the run starts, 15 as it ends)
  (``page_origin``; ``clock_map_ms`` says how tight, ``page_clock_offset_error_ms``
  how far the page's own ping-synced offset is from it). So ``capture_to_shown_ms``
  (p50, p99) is expectedDisplayTime (never before the callback: the page draws the
  frame into its WebGL view in it) − the frame's capture time, per frame; not the page
  meter's capture → decoded plus an estimate. ``frozen_share`` and
  ``longest_freeze_ms`` over the shown times, with the modelled viewer's definitions
  (video_figures: gaps > 200 ms, whole gaps counted, the outage and the second after
  it left out); ``fps``: callbacks a second (frames the page drew); ``frames``;
  ``lease_kept`` (that leg's command client). Beside them: ``fps_presented`` and
  ``webrtc`` (Chromium's own freeze counters, inbound-rtp ``freezeCount`` and
  ``totalFreezesDuration``, read once a second: ``frozen_share``, ``freezes``,
  ``fps_decoded``; the decoder's output as the <video> got it, so on a machine whose
  software GPU starves the page's drawing, the link's part apart from the page's), and
  ``callbacks_missed`` (the compositor's presentedFrames: frames presented to the
  hidden <video> and replaced before a callback saw them), ``decoded_latency_ms`` (the
  page's own capture → decoded meter, view/glass.ts, p50/p99; its worker reads frames
  from a queue, so on a starved machine it lags, and can read above capture → shown),
  ``receive_to_shown_ms`` (the metadata's receiveTime to the shown time),
  ``capture_to_callback_ms`` and ``expected_display_after_callback_ms`` (capture →
  shown split at the callback's ``now``: headless Chromium expects the display
  50-120 ms after the callback on this machine),
  ``before_outage``, ``page_operator`` (the server welcomed the page as operator),
  ``cpu_cores`` and ``cpu_by_kind`` (Chromium's processes' CPU over the run, in
  cores), and the leg's force and command figures (``command_p99_ms``,
  ``control_lost_at_s``, …). On this 2-core machine the software GPU takes most of a
  core and the page's main thread draws a few frames a second: Chromium's figures are
  the machine's as much as the link's.
* **viewer** (the modelled leg): an aiortc peer that decodes every frame and reads the
  capture time from the picture's timecode (drivers/camera/timecode), made to receive
  as libwebrtc's receiver does (harness/wan_receiver.py): RED and ULPFEC undone and
  lost packets rebuilt, a key frame after a gap decoded at once, NACKs for up to 1000
  packets (``BENCH_WAN_NACK_LIST``), each frame shown on the playout delay the server
  stamps (its time on the fastest frames' schedule plus that delay; the current delay
  moves 100 ms a second, as libwebrtc's). Figures at the frame's *shown* time: fps,
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

Halfway through each leg, the link goes down both ways for ``--outage`` s (1.5 s;
NetemPair.link_down): a leg's ``lease_kept`` says its command client held control from
the start to the end, through the outage (the server's lease grace is 2 s). The steady
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
import concurrent.futures
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


def _get_json(base: str, path: str, token: str = "") -> Any:
    """GET ``path`` (with the operator token if given: GET /api/v1/video then names
    each viewer's ``peer_id``)."""
    import httpx

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    try:
        return httpx.get(base + path, timeout=10, headers=headers).json()
    except Exception as exc:  # a figure missing is reported, not fatal
        return {"error": repr(exc)}


async def _open_viewer(
    base: str, token: str, timeout: float = 30.0
) -> tuple[Any, Any, dict[str, str]]:
    """harness.aiortc_viewers.open_viewer with the operator's token on the offer
    (``Authorization: Bearer``, as the page sends it when opened with ``?token=``);
    tokenless (an observer's peer) when ``token`` is empty. Also returns the server's
    peer id and secret."""
    import httpx
    from aiortc import RTCPeerConnection, RTCSessionDescription

    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    tracks: asyncio.Queue[Any] = asyncio.Queue()
    pc.on("track", tracks.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    async with httpx.AsyncClient(base_url=base, timeout=timeout, headers=headers) as http:
        r = await http.post(
            "api/v1/webrtc/offer", json={"sdp": pc.localDescription.sdp, "type": "offer"}
        )
        if r.status_code != 200:
            await pc.close()
            raise RuntimeError(f"the server refused the offer: HTTP {r.status_code} {r.text}")
        answer = r.json()
        await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    peer = {"peer_id": answer.get("peer_id", ""), "peer_secret": answer.get("peer_secret", "")}
    return pc, await asyncio.wait_for(tracks.get(), timeout), peer


def _close_peer(base: str, peer_id: str, secret: str = "", token: str = "") -> int | None:
    """DELETE the server's peer (its secret, or the operator token: any), as the page
    does on leaving: a peer left to ICE's timeout keeps being sent video (and stays the
    newest operator's peer) for half a minute. The HTTP status (404: gone already)."""
    import httpx

    if not peer_id:
        return None
    headers = {"X-Telerobot-Client": "bench.wan"}  # (the edge's rule for a non-JSON DELETE)
    if secret:
        headers["X-Peer-Secret"] = secret
    if token:
        headers["Authorization"] = f"Bearer {token}"
    try:
        return httpx.delete(
            f"{base}api/v1/webrtc/{peer_id}", headers=headers, timeout=10
        ).status_code
    except Exception:
        return None


def _own_viewer(viewers: list[dict[str, Any]], peer_id: str | None) -> dict[str, Any] | None:
    """This client's entry among GET /api/v1/video's viewers: the one with its peer id
    (named to the operator), else the first (the only one, mostly)."""
    mine = [v for v in viewers if peer_id and v.get("peer_id") == peer_id]
    return mine[0] if mine else viewers[0] if viewers else None


def role_viewer(base: str, token: str = "", bench_token: str = "") -> dict[str, Any]:
    """The modelled viewer; the operator's peer with ``token`` (else an observer's).
    ``bench_token``: the operator token, to read the server's figures with the peers'
    ids (this peer's own entry) whichever the viewer is."""
    import aiortc.rtcrtpreceiver as receiver

    from harness import wan_receiver
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
        pc, track, peer = await _open_viewer(base, token)
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
                status = await asyncio.to_thread(_get_json, base, "api/v1/video", bench_token)
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
        status = await asyncio.to_thread(_get_json, base, "api/v1/video", bench_token)
        await pc.close()
        closed = await asyncio.to_thread(_close_peer, base, peer["peer_id"], peer["peer_secret"])
        return {
            "peer_id": peer["peer_id"],
            "peer_closed": closed,
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


# Injected into the operator page once it shows video (called with the full picture's
# width, both eyes, for the low layer's scale). For every frame the compositor shows,
# requestVideoFrameCallback's `now` and metadata (expectedDisplayTime,
# presentationTime, presentedFrames, and for a WebRTC source captureTime, receiveTime,
# rtpTimestamp, processingDuration), all on the page's clock (performance.now), and the
# timecode in that frame's picture: the frame is taken from the <video> in the callback
# (new VideoFrame(video): the frame the metadata is about) and its 2-row strip through
# the blocks copied out, as view/glass.ts reads a decoded frame (same strip, same
# threshold). Beside it, every capture → decoded figure the page's own meter
# (view/glass.ts) adds, stamped when its listener hears it (batched every 250 ms in
# the meter's worker: the time is for choosing the steady part only), and whether the
# page ever held the lease (its STATE's YOU_HAVE_CONTROL, polled every 100 ms).
# Bounded: a 20 s run at 30 fps is 600 of each.
PAGE_PROBE = """
(fullWidth) => {
  const video = document.getElementById("video");
  const frames = (window.__frames = []);
  const ages = (window.__ages = []);
  const lease = (window.__lease = { samples: 0, held: 0 });
  const even = (v) => 2 * Math.max(0, Math.round(v / 2));
  const strip = (scale) => {  // view/glass.ts's timecodeStrip
    const x = even(8 * scale);
    const rect = { x, y: even(16 * scale), width: Math.max(2, even(512 * scale)), height: 2 };
    const xs = Array.from({ length: 32 }, (_, i) =>
      Math.min(rect.width - 1, Math.max(0, Math.round((8 + i * 16 + 8) * scale) - x)));
    return { rect, xs };
  };
  const read = async (frame, rec) => {
    try {
      const { rect, xs } = strip(frame.displayWidth / fullWidth);
      const buffer = new Uint8Array(frame.allocationSize({ rect }));
      const layout = await frame.copyTo(buffer, { rect });
      const format = frame.format ?? "";
      const rgb = format.startsWith("RGB") || format.startsWith("BGR");
      const at = layout[0]?.offset ?? 0;
      let code = 0;
      for (const x of xs) {
        code = code * 2 + ((buffer[at + (rgb ? x * 4 + 1 : x)] ?? 0) > 128 ? 1 : 0);
      }
      rec.code = code;
    } catch (e) {
      rec.error = String(e).slice(0, 160);
    } finally {
      frame.close();
    }
  };
  const tick = (now, md) => {
    video.requestVideoFrameCallback(tick);
    if (frames.length >= 100000) return;
    const rec = {
      now, expected: md.expectedDisplayTime, presented: md.presentationTime,
      count: md.presentedFrames, width: md.width, height: md.height,
      capture: md.captureTime ?? null, receive: md.receiveTime ?? null,
      rtp: md.rtpTimestamp ?? null, processing: md.processingDuration ?? null, code: null,
    };
    frames.push(rec);
    let frame;
    try {
      frame = new VideoFrame(video);
    } catch (e) {
      rec.error = String(e).slice(0, 160);
      return;
    }
    void read(frame, rec);
  };
  video.requestVideoFrameCallback(tick);
  window.telerobot.glass.listen((v) => {
    if (ages.length < 100000) ages.push([performance.now(), v]);
  });
  // WebRTC's own freeze counters (inbound-rtp freezeCount, totalFreezesDuration: the
  // decoder's frames as the <video> sink received them, not the page's drawing), and the
  // frames decoded, once a second with the peer they are of (a new peer starts at 0).
  const rtc = (window.__rtc = []);
  // And what the link did to them: loss, repairs (FEC and NACK), the jitter buffer.
  const RTC_MORE = ["packetsReceived", "packetsLost", "fecPacketsReceived", "fecPacketsDiscarded",
    "nackCount", "pliCount", "framesReceived", "framesDropped", "jitterBufferDelay",
    "jitterBufferEmittedCount", "jitterBufferTargetDelay"];
  setInterval(async () => {
    const id = window.telerobot.video.peerId;
    const stats = await window.telerobot.video.stats().catch(() => null);
    if (!stats || rtc.length >= 10000) return;
    stats.forEach((r) => {
      if (r.type === "inbound-rtp" && r.kind === "video") {
        const more = {};
        for (const k of RTC_MORE) more[k] = r[k] ?? null;
        rtc.push([performance.now(), id, r.freezeCount ?? null, r.totalFreezesDuration ?? null,
          r.framesDecoded ?? null, more]);
      }
    });
  }, 1000);
  const peers = (window.__peers = []);
  setInterval(() => {
    const id = window.telerobot.video.peerId;  // a new one: the page re-negotiated
    if (id && (!peers.length || peers[peers.length - 1][1] !== id) && peers.length < 1000) {
      peers.push([performance.now(), id]);
    }
    const s = window.telerobot.state;
    if (!s) return;
    lease.samples += 1;
    if (s.flags & 1) lease.held += 1;  // StateFlags.YOU_HAVE_CONTROL
  }, 100);
}
"""


def _clock_samples(page: Any, n: int = 15) -> list[tuple[float, float, float]]:
    """(monotonic before, the page's performance.now() in ms, monotonic after), n times."""
    samples = []
    for _ in range(n):
        t0 = time.monotonic()
        at = float(page.evaluate("performance.now()"))
        samples.append((t0, at, time.monotonic()))
    return samples


def _cpu_seconds(processes: list[Any]) -> dict[int, tuple[str, float]]:
    """Each process's kind (Chromium's --type=, "browser" for its main process,
    "playwright-driver" for anything not Chromium) and its CPU seconds."""
    import psutil

    seen: dict[int, tuple[str, float]] = {}
    for process in processes:
        try:
            argv = process.cmdline()
            kind = "browser" if argv and "chromium" in argv[0] else "playwright-driver"
            for arg in argv:
                if arg.startswith("--type="):
                    kind = arg.split("=", 1)[1]
            times = process.cpu_times()
            seen[process.pid] = (kind, times.user + times.system)
        except psutil.Error:
            continue
    return seen


def cpu_share(
    before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]], wall_s: float
) -> dict[str, Any]:
    """The CPU the processes took between two ``_cpu_seconds`` snapshots, in cores (1.0:
    one core all the time), by kind (gpu-process, renderer, …) and Chromium's in all
    (``cores``: Playwright's driver left out). A process gone before ``after`` is not
    counted."""
    by_kind: dict[str, float] = {}
    for pid, (kind, cpu) in after.items():
        used = cpu - before.get(pid, (kind, 0.0))[1]
        by_kind[kind] = by_kind.get(kind, 0.0) + used / wall_s
    cores = sum(v for k, v in by_kind.items() if k != "playwright-driver")
    return {"cores": cores, "by_kind": by_kind, "wall_s": wall_s}


def role_browser(base: str, token: str = "", bench_token: str = "") -> dict[str, Any]:
    """The viewer as an operator has it: Debian's Chromium with the operator page, in
    this (the client's) namespace; opened with ``?token=`` (the operator's page: its
    REST requests, its video offer among them, carry the token) unless ``token`` is
    empty (an observer's page). The page never takes the lease by itself (only its
    Take button, the alert's retake offer after it lost control, or the dead-man while
    a policy drives do); the probe checks it did not."""
    import psutil
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import sync_playwright

    from harness.chromium import ARGS, yield_software_gpu

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        # A small window: what is measured is the link, and on this 2-core machine the
        # software GPU's work grows with the pixels it draws (at 1280×720 it took the
        # server's encoder down to 12 fps).
        page = browser.new_page(viewport={"width": 640, "height": 400})
        page.goto(base + (f"?token={token}" if token else ""))
        yield_software_gpu()
        page.wait_for_function("window.telerobot && window.telerobot.view", timeout=60_000)
        # A few frames shown, or on for the run without them after 20 s: an operator's
        # peer on a narrow link can take a minute to show ten (bad: 60 s in one run).
        with contextlib.suppress(PlaywrightTimeout):
            page.wait_for_function("window.telerobot.view.frames > 3", timeout=20_000, polling=100)
        frames_at_ready = page.evaluate("window.telerobot.view.frames")
        full_width = 2 * int(_get_json(base, "api/v1/video")["width"])  # both eyes
        page.evaluate(PAGE_PROBE, full_width)
        renegotiated_before = page.evaluate("window.telerobot.video.renegotiations")
        clock = _clock_samples(page)  # (and as many at the end: the tightest is taken)
        chromium = psutil.Process().children(recursive=True)
        cpu_before, cpu_at = _cpu_seconds(chromium), time.monotonic()
        # The server's per-viewer figures once a second, as the aiortc viewer polls them
        # (with the operator token: each entry names its peer).
        polls: list[tuple[float, Any]] = []
        stop = threading.Event()

        def poll() -> None:
            while not stop.wait(1.0):
                status = _get_json(base, "api/v1/video", bench_token)
                polls.append((time.monotonic(), (status.get("stats") or {}).get("viewers")))

        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        print("ready", flush=True)
        sys.stdin.readline()
        stop.set()
        cpu = cpu_share(cpu_before, _cpu_seconds(chromium), time.monotonic() - cpu_at)
        frames, ages, lease, client, layer, peer_id, renegotiations, peers, rtc = page.evaluate(
            "[window.__frames, window.__ages, window.__lease, window.telerobot.client,"
            " window.telerobot.hud && window.telerobot.hud.rows.find((r) => r.key === 'video'),"
            " window.telerobot.video.peerId, window.telerobot.video.renegotiations,"
            " window.__peers, window.__rtc]"
        )
        clock += _clock_samples(page)
        status = _get_json(base, "api/v1/video", bench_token)
        page.close()  # pagehide: the page closes its peer on the server (DELETE, keepalive)
        time.sleep(0.5)
        browser.close()
    # And if its DELETE did not get out before the browser went: the operator token's.
    closed = _close_peer(base, peer_id or "", token=bench_token)
    return {
        "peer_id": peer_id,
        "peer_closed": closed,
        "renegotiations": renegotiations - renegotiated_before,
        "frames_at_ready": frames_at_ready,
        "peers": peers,  # [page time (ms), peer id]: the page's peers, each new one's time
        "rtc": rtc,  # [page time (ms), peer id, freezeCount, totalFreezesDuration, decoded]
        "rvfc": frames,
        "glass": ages,  # [page time (ms), capture → decoded (ms)]
        "clock": clock,
        "lease": lease,
        "page_operator": (client or {}).get("operator"),
        "page_clock_offset_s": (client or {}).get("offset"),
        "cpu": cpu,
        "bytes_at": [],
        "packets": [],
        "polls": polls,
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
        # (a client's own ages are the operator's to read: the token)
        safety = await asyncio.to_thread(
            _get_json, base, f"api/v1/safety?client={op.client_id}", token
        )
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


def run_role(role: str, base: str, token: str, hz: float, viewer_token: str = "") -> None:
    if role == "viewer":
        out = role_viewer(base, viewer_token, token)
    elif role == "browser":
        out = role_browser(base, viewer_token, token)
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
    viewers = ((out.get("status") or {}).get("stats") or {}).get("viewers") or []
    decoded = [
        age * 1000 for t, age in out.get("decoded") or [] if age is not None and _in(t, segments)
    ]
    delays = out.get("playout_delays_ms") or []
    own = _own_viewer(viewers, out.get("peer_id"))
    server_fec = (own.get("fec") if own else None) or {}
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
        "server_viewer": own,
    }


# A code read off a picture further than this behind the time it was shown is a misread
# (as view/glass.ts drops one 5 s behind).
SHOWN_AGE_MAX_S = 5.0


def page_origin(samples: list[tuple[float, float, float]]) -> float:
    """The zero of the page's clock (performance.now()) on this machine's monotonic
    one, in s: from (monotonic before, performance.now() in ms, monotonic after)
    samples, the one read in the shortest time (its middle). Chromium's clock on Linux
    is CLOCK_MONOTONIC from the page's start, as is the server's (the timecode's): one
    offset maps it, good to half that shortest time."""
    t0, at, t1 = min(samples, key=lambda s: s[2] - s[0])
    return (t0 + t1) / 2 - at / 1000


def shown_frames(records: list[dict[str, Any]], origin: float) -> list[tuple[float, float | None]]:
    """Each frame the page showed (one requestVideoFrameCallback record, PAGE_PROBE):
    (shown, capture → shown), in s on the monotonic clock. Shown: the callback's
    ``expectedDisplayTime`` (when the compositor expects the frame on the screen; else
    ``presentationTime``, else the callback's ``now``), never before the callback's
    ``now`` (the page draws the frame then, into its WebGL view; a starved compositor's
    expected time can come before it). Capture: the timecode read off that frame's own
    picture (``code``, the server's clock at capture, 0.1 ms units
    modulo 2**32), taken back from the shown time; None when unread or a misread (over
    ``SHOWN_AGE_MAX_S``)."""
    from telerobot.drivers.camera import timecode

    frames: list[tuple[float, float | None]] = []
    for r in records:
        at = next((r[k] for k in ("expected", "presented", "now") if r.get(k)), 0.0)
        shown = origin + max(float(at), float(r.get("now") or 0.0)) / 1000
        code = r.get("code")
        age = None
        if isinstance(code, int | float) and not isinstance(code, bool) and code >= 0:
            age = timecode.elapsed(int(code), shown)
            if age > SHOWN_AGE_MAX_S:
                age = None
        frames.append((shown, age))
    return frames


def presented_counts(
    records: list[dict[str, Any]], origin: float, segments: Segments
) -> dict[str, Any]:
    """From the callbacks' ``presentedFrames``: frames the compositor presented per
    second in the segments (a frame presented and replaced before the next callback
    counts here, not among the callbacks), and how many such frames no callback saw.
    The counter starts again with a new stream (the page re-negotiated): a count
    below the one before is frames since then."""
    presented = 0
    missed = 0
    for lo, hi in segments:
        inside = [
            int(r["count"])
            for r in records
            if r.get("count") is not None
            and lo <= origin + float(r.get("expected") or r["now"]) / 1000 <= hi
        ]
        for a, b in itertools.pairwise(inside):
            presented += b - a if b >= a else b
            missed += max(0, b - a - 1) if b >= a else max(0, b - 1)
    span = sum(hi - lo for lo, hi in segments)
    return {"fps_presented": presented / span if span else None, "callbacks_missed": missed}


def peer_history(
    polls: list[tuple[float, Any]], peer_id: str, since: float
) -> dict[str, Any] | None:
    """What the server said of one peer in the polls (GET /api/v1/video's viewers,
    once a second): polls naming it, the time since ``since`` it was first and last
    named, its last layer and frames, and its rate (the operator's own stream's, if it
    had it): the lowest and the last kbps, the last reason and cuts; its link's last
    estimate and round trip."""
    seen = [
        (t, v)
        for t, vs in polls
        for v in vs or []
        if isinstance(v, dict) and v.get("peer_id") == peer_id
    ]
    if not seen:
        return None
    kbps = [(v.get("rate") or {}).get("kbps") for _, v in seen]
    rates = [float(r) for r in kbps if r is not None]
    t_last, last = seen[-1]
    rate, link = last.get("rate") or {}, last.get("link") or {}
    return {
        "polls": len(seen),
        "first_s": seen[0][0] - since,
        "last_s": t_last - since,
        "layer": last.get("layer"),
        "layers": sorted({str(v.get("layer")) for _, v in seen}),
        "frames": last.get("frames"),
        "rate_kbps_min": min(rates) if rates else None,
        "rate_kbps": rate.get("kbps"),
        "rate_why": rate.get("why"),
        "rate_cuts": rate.get("cuts"),
        "estimated_kbps": link.get("estimated_kbps"),
        "rtt_ms": link.get("rtt_ms"),
    }


def webrtc_freezes(samples: list[list[Any]], origin: float, segments: Segments) -> dict[str, Any]:
    """Chromium's own freeze counters (PAGE_PROBE's ``__rtc``, once a second) over the
    steady segments: the time its decoder's output was frozen by WebRTC's definition (a
    frame later than max(3 × the mean frame interval, the mean + 150 ms)) as a share of
    the time, the freezes, and the frames decoded a second. Only pairs of samples of one
    peer both inside one segment count, so a re-negotiation's gap (a new peer's counters
    start at 0) is left out here and counted by the page's own figures."""
    frozen = freezes = decoded = 0.0
    span = 0.0
    more: dict[str, float] = {}
    for a, b in itertools.pairwise(samples):
        ta, tb = origin + a[0] / 1000, origin + b[0] / 1000
        same = a[1] == b[1] and all(v is not None for v in (*a[2:5], *b[2:5]))
        inside = any(lo <= ta and tb <= hi for lo, hi in segments)
        if not (same and inside) or b[4] < a[4]:
            continue
        span += tb - ta
        freezes += b[2] - a[2]
        frozen += b[3] - a[3]
        decoded += b[4] - a[4]
        for key, value in (b[5] if len(b) > 5 else {}).items():
            before = a[5].get(key) if len(a) > 5 else None
            if value is not None and before is not None:
                more[key] = more.get(key, 0.0) + value - before
    buffered = more.get("jitterBufferEmittedCount")

    def buffered_ms(total: str) -> float | None:
        """A jitter-buffer total (s) over the frames it let out, in ms a frame."""
        return 1000 * more[total] / buffered if buffered and total in more else None

    return {
        "frozen_share": frozen / span if span else None,
        "freezes": int(freezes),
        "fps_decoded": decoded / span if span else None,
        "seconds": span,
        # The link's work on them, over the same pairs (inbound-rtp's counters' growth).
        "counters": {k: v for k, v in more.items() if not k.startswith("jitterBuffer")},
        "jitter_buffer_ms": buffered_ms("jitterBufferDelay"),
        "jitter_buffer_target_ms": buffered_ms("jitterBufferTargetDelay"),
    }


def chromium_figures(
    out: dict[str, Any], row: dict[str, Any], early: dict[str, Any], segments: Segments
) -> dict[str, Any]:
    """The Chromium leg's viewer figures (``row``/``early``: its video_figures over the
    steady segments and the first half, from ``shown_frames``), with the page's own
    counters: capture → decoded from its meter (view/glass.ts, on the page's ping-synced
    clock), receive → shown from the callbacks' metadata, the lease as the page saw it,
    and the browser's CPU."""
    records = out["rvfc"]
    origin = page_origin(out["clock"])
    decoded = [ms for t, ms in out.get("glass") or [] if _in(origin + t / 1000, segments)]
    steady = [
        r for r in records if _in(origin + float(r.get("expected") or r["now"]) / 1000, segments)
    ]
    receive = [
        r["expected"] - r["receive"] for r in steady if r.get("receive") and r.get("expected")
    ]
    # The callback's own time against the expected display: capture → the callback
    # (the page draws then) is capture → shown less this.
    ahead = [max(0.0, r["expected"] - r["now"]) for r in steady if r.get("expected")]
    to_callback = [
        age * 1000 - max(0.0, r["expected"] - r["now"])
        for r, (shown, age) in zip(records, shown_frames(records, origin), strict=True)
        if age is not None and r.get("expected") and _in(shown, segments)
    ]
    # The metadata's own capture time (a remote source's, through RTCP sender reports),
    # against the timecode's: how far the browser's estimate is off.
    meta = [
        (origin + r["capture"] / 1000 - (shown - age)) * 1000
        for r, (shown, age) in zip(records, shown_frames(records, origin), strict=True)
        if r.get("capture") and age is not None
    ]
    errors = [r["error"] for r in records if r.get("error")]
    lease = out.get("lease") or {}
    cpu = out.get("cpu") or {}
    offset = out.get("page_clock_offset_s")
    fastest = min(s[2] - s[0] for s in out["clock"])
    return {
        "frozen_share": row["frozen_share"],
        "longest_freeze_ms": row["longest_freeze_ms"],
        "capture_to_shown_ms": {"p50": row["latency_p50_ms"], "p99": row["latency_p99_ms"]},
        "fps": row["fps"],
        "lease_kept": row["lease_kept"],
        "frames": sum(1 for r in steady),
        "frames_unreadable": row["frames_unreadable"],
        "read_errors": len(errors),
        "read_error": errors[0] if errors else None,
        "decoded_latency_ms": {"p50": _pct(decoded, 50), "p99": _pct(decoded, 99)},
        "receive_to_shown_ms": {"p50": _pct(receive, 50), "p99": _pct(receive, 99)},
        "capture_to_callback_ms": {"p50": _pct(to_callback, 50), "p99": _pct(to_callback, 99)},
        "expected_display_after_callback_ms": {"p50": _pct(ahead, 50), "p99": _pct(ahead, 99)},
        "metadata_capture_minus_timecode_ms": _pct(meta, 50),
        **presented_counts(records, origin, segments),
        "webrtc": webrtc_freezes(out.get("rtc") or [], origin, segments),
        "frozen_share_incl_outage": row["frozen_share_incl_outage"],
        "video_recovery_ms": row["video_recovery_ms"],
        "before_outage": {
            "fps": early["fps"],
            "capture_to_shown_ms": {"p50": early["latency_p50_ms"], "p99": early["latency_p99_ms"]},
            "frozen_share": early["frozen_share"],
            "longest_freeze_ms": early["longest_freeze_ms"],
        },
        "page_operator": out.get("page_operator"),
        "page_held_lease": bool(lease.get("held")),
        # The page's peers (a new one each time it re-negotiated, e.g. after a stall),
        # from when (s since the steady run's start), and the server's figures of each.
        "renegotiations": out.get("renegotiations"),
        "frames_at_ready": out.get("frames_at_ready"),
        "page_peers": [
            {
                "at_s": origin + t / 1000 - segments[0][0],
                "peer_id": peer,
                "server": peer_history(out.get("polls") or [], peer, segments[0][0]),
            }
            for t, peer in out.get("peers") or []
        ],
        "page_state_samples": lease.get("samples"),
        "cpu_cores": cpu.get("cores"),
        "cpu_by_kind": cpu.get("by_kind"),
        # The page's own clock sync (server − page, from its pings over the link)
        # against the mapping used here (one machine's clock, read in ≤ clock_map_ms).
        "page_clock_offset_error_ms": None if offset is None else (offset - origin) * 1000,
        "clock_map_ms": fastest * 1000,
        "server_viewer": row["server_viewer"],
        "hud_video_row": out.get("hud_video_row"),
    }


def layer_switches(out: dict[str, Any], window: tuple[float, float]) -> tuple[int, str]:
    """From GET /api/v1/video's per-viewer entries (this viewer's: ``_own_viewer``): a
    switch counter if the server has one, else the changes of ``layer`` polled once a
    second."""
    viewers = ((out.get("status") or {}).get("stats") or {}).get("viewers") or []
    peer_id = out.get("peer_id")
    own = _own_viewer(viewers, peer_id)
    counters = sorted(
        k for k, x in (own or {}).items()
        if "layer" in k.lower() and "switch" in k.lower() and isinstance(x, int | float)
    )  # fmt: skip
    if own and counters:
        return int(own.get(counters[0]) or 0), (
            f"GET /api/v1/video viewers[].{counters[0]} at the end (whole connection)"
        )
    polled = [(t, _own_viewer(vs or [], peer_id)) for t, vs in out.get("polls") or []]
    seen = [
        str(v.get("layer")) for t, v in polled if v and "layer" in v and window[0] <= t <= window[1]
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
    viewer_token: str = "",
) -> subprocess.Popen[str]:
    process = "browser" if role == "viewer" and viewer == "browser" else role
    # Asked again 1.5 round trips after the last ask (the link's jitter on top).
    renack_ms = 1.5 * max(rtt_ms, 10.0) if viewer == "aiortc" else 0.0
    env = {
        **os.environ,
        "BENCH_WAN_TOKEN": token,
        "BENCH_WAN_VIEWER_TOKEN": viewer_token,
        "BENCH_WAN_RENACK_MS": str(renack_ms),
    }
    return subprocess.Popen(
        [*pair.client_prefix, sys.executable, "-m", "bench.wan", "--role", process,
         "--base", base, "--command-hz", str(hz)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env=env, cwd=REPO,
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


def _wait_ready(procs: dict[str, subprocess.Popen[str]], timeout: float) -> None:
    """Until every client said "ready"; one that ended first, or all not ready within
    ``timeout`` s, is a RuntimeError with its stderr (the clients are killed)."""
    said: dict[str, bool] = {}
    done = {role: threading.Event() for role in procs}

    def watch(role: str, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        while line := proc.stdout.readline():
            if line.strip() == "ready":
                said[role] = True
                break
        done[role].set()  # (ready, or its stdout ended)

    for role, proc in procs.items():
        threading.Thread(target=watch, args=(role, proc), daemon=True).start()
    deadline = time.monotonic() + timeout
    for role, proc in procs.items():
        if done[role].wait(max(0.0, deadline - time.monotonic())) and said.get(role):
            continue
        for other in procs.values():
            other.kill()  # (a client's stderr ends only with it)
        why = proc.communicate()[1][-3000:]
        raise RuntimeError(f"the {role} client did not start within {timeout:.0f} s: {why}")


BEFORE_KEYS = (
    "fps", "latency_p50_ms", "latency_p99_ms", "frozen_share", "longest_freeze_ms",
    "force_p50_ms", "force_p99_ms", "force_lost", "command_p50_ms", "command_p99_ms",
)  # fmt: skip


def run_leg(
    pair: NetemPair,
    base: str,
    token: str,
    seconds: float,
    outage_s: float,
    hz: float,
    viewer: str = "aiortc",
    rtt_ms: float = 100.0,
    viewer_token: str = "",
) -> dict[str, Any]:
    """One leg on the link as it is: the viewer (``viewer``: an aiortc kind or
    "browser"), the force and the command client at once, the outage halfway. Today's
    row (video, force and command figures); a browser leg's also has ``chromium``."""
    spawned = time.monotonic()
    procs = {
        role: _spawn(pair, role, base, token, hz, viewer, rtt_ms, viewer_token) for role in ROLES
    }
    try:
        # (Chromium shows its first frames in 5-15 s on a quiet machine; its page waits
        # up to 60 s for the page and 30 s more for frames.)
        _wait_ready(procs, 150.0)
        time.sleep(1.0)  # the rate settles after the first keyframe
        t_start = time.monotonic()
        time.sleep(seconds / 2)
        t_down = time.monotonic()
        pair.link_down(outage_s)
        t_up = time.monotonic()
        time.sleep(max(0.0, t_start + seconds + outage_s - time.monotonic()))
        t_end = time.monotonic()
        # All told to stop at once (each then reads the server's figures over the link).
        with concurrent.futures.ThreadPoolExecutor(len(procs)) as pool:
            collected = {role: pool.submit(_collect, proc, role) for role, proc in procs.items()}
            results = {role: f.result() for role, f in collected.items()}
        collected_at = time.monotonic()
        if dump := os.environ.get("BENCH_WAN_DUMP"):  # raw records, for a closer look
            path = dump if viewer != "browser" else f"{dump}.chromium"
            with open(path, "w") as f:
                json.dump({"times": [t_start, t_down, t_up, t_end], **results}, f)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    segments = [(t_start, t_down), (t_up + RECOVER_S, t_end)]
    before = [(t_start, t_down)]  # the link as it is, no outage backlog yet
    seen = results["viewer"]
    if viewer == "browser":  # the frames the page showed, capture → shown on each
        seen = {**seen, "frames": shown_frames(seen["rvfc"], page_origin(seen["clock"]))}
    early = {
        **video_figures(seen, before, t_up),
        **force_figures(results["force"], before, t_up),
        **command_figures(results["command"], before, t_down, t_up),
    }
    row = {
        "before_outage": {k: early[k] for k in BEFORE_KEYS},
        **video_figures(seen, segments, t_up),
        **force_figures(results["force"], segments, t_up),
        **command_figures(results["command"], segments, t_down, t_up),
        "steady_s": sum(hi - lo for lo, hi in segments),
        "outage_s": t_up - t_down,
        "viewer_as": "operator" if viewer_token else "observer",
        # This leg's wall time: its clients' start (up to their "ready"), the run, the
        # collection of their figures.
        "leg_s": {
            "start": t_start - 1.0 - spawned,
            "run": t_end - t_start,
            "collect": collected_at - t_end,
        },
    }
    if viewer == "browser":
        row["chromium"] = chromium_figures(results["viewer"], row, early, segments)
    return row


# The keys of a Chromium leg's own force and command figures kept in its ``chromium``.
LEG_KEYS = (
    "force_p50_ms", "force_p99_ms", "force_lost", "force_transport", "command_p50_ms",
    "command_p99_ms", "commands_sent", "commands_executed", "commands_refused",
    "stale_executed", "executed_age_ms", "control_lost_at_s", "sessions_resumed", "steady_s",
)  # fmt: skip


def run_profile(
    pair: NetemPair,
    base: str,
    token: str,
    seconds: float,
    outage_s: float,
    hz: float,
    viewer: str = "both",
    rtt_ms: float = 100.0,
    viewer_token: str = "",
) -> dict[str, Any]:
    """One profile: with ``viewer`` "both", a Chromium leg and then a modelled-viewer
    (aiortc) leg on the same link, one after the other; else the one leg. The row is
    the modelled leg's (the Chromium leg's alone) with ``chromium`` from the Chromium
    leg (its own force and command figures inside), ``lease_kept`` true only if the
    command client kept the lease in every leg, ``lease_kept_by_leg`` each, and
    ``emulator`` per leg."""
    legs = ("browser", "aiortc") if viewer == "both" else (viewer,)
    rows: dict[str, dict[str, Any]] = {}
    emulator: dict[str, Any] = {}
    for i, leg in enumerate(legs):
        if i:
            time.sleep(2.0)  # the last leg's peers and sessions gone, the link drained
        counted = pair.forwarder_counters()
        rows[leg] = run_leg(pair, base, token, seconds, outage_s, hz, leg, rtt_ms, viewer_token)
        if leg == "browser":
            rows[leg]["chromium"]["leg_s"] = rows[leg]["leg_s"]
        emulator["chromium" if leg == "browser" else "modelled"] = emulator_figures(
            counted, pair.forwarder_counters()
        )
    name = {"browser": "chromium"}
    row = rows[legs[-1]]
    if "browser" in rows and row is not rows["browser"]:
        b = rows["browser"]
        row["chromium"] = {**b["chromium"], **{k: b.get(k) for k in LEG_KEYS}}
    kept = {name.get(leg, "modelled"): bool(r["lease_kept"]) for leg, r in rows.items()}
    row["lease_kept_by_leg"] = kept
    row["lease_kept"] = all(kept.values())
    row["viewer"] = viewer
    row["emulator"] = emulator
    return row


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
    # The same picture goals for Chromium's own figures (the browser leg).
    chromium = row.get("chromium") or {}
    longest = chromium.get("longest_freeze_ms")
    if chromium and name == "mobile":
        out["chromium_fps_ge_25"] = (chromium.get("fps") or 0) >= 25
        frozen = chromium.get("frozen_share")
        out["chromium_frozen_le_2pct"] = frozen is not None and frozen <= 0.02
        out["chromium_longest_freeze_le_300ms"] = (longest or math.inf) <= 300
    if chromium and name == "bad":
        out["chromium_no_stall_over_1s"] = (longest or math.inf) <= 1000
        out["chromium_longest_freeze_le_500ms"] = (longest or math.inf) <= 500
    return out


def _brief(chromium: dict[str, Any]) -> str:
    """The Chromium viewer's headline figures on one line."""
    shown = chromium.get("capture_to_shown_ms") or {}

    def f(v: Any) -> str:
        return "-" if v is None else f"{v:.3g}" if isinstance(v, float) else str(v)

    return (
        f"fps {f(chromium.get('fps'))} frozen {f(chromium.get('frozen_share'))}"
        f" longest {f(chromium.get('longest_freeze_ms'))} ms capture→shown p50"
        f" {f(shown.get('p50'))} p99 {f(shown.get('p99'))} ms lease_kept"
        f" {chromium.get('lease_kept')} cpu {f(chromium.get('cpu_cores'))} cores"
    )


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
        choices=("both", *VIEWERS),
        default="both",
        help="who watches: both (a Chromium leg, then a modelled-viewer leg, on the same"
        " link), an aiortc peer that decodes in Python and models libwebrtc's playout, or"
        " Debian's Chromium with the operator page (what an operator has; heavier here)",
    )
    p.add_argument(
        "--observer-viewer",
        action="store_true",
        help="the viewers connect without the operator token (an observer's peer);"
        " by default they are the operator's",
    )
    p.add_argument("--role", choices=(*ROLES, "browser"), help=argparse.SUPPRESS)
    p.add_argument("--base", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role:
        run_role(
            args.role,
            args.base,
            os.environ.get("BENCH_WAN_TOKEN", ""),
            args.command_hz,
            os.environ.get("BENCH_WAN_VIEWER_TOKEN", ""),
        )
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
            profile_started = time.monotonic()
            pair.apply(profile)
            link = measure_link(pair, probes=args.probes, interval_s=probe_interval_s(profile))
            # The same link under a 1 kHz stream (as the forces): a FIFO link holds
            # packets closer than its jitter behind each other, so this stream's own
            # one-way delay is the floor for any force transport.
            dense = measure_link(pair, probes=2000, interval_s=0.001)
            measured_s = time.monotonic() - profile_started
            time.sleep(max(0.0, ready_at - time.monotonic()))
            row = run_profile(
                pair,
                base,
                token,
                args.seconds,
                args.outage,
                args.command_hz,
                args.viewer,
                rtt_ms=float(link.figures().get("rtt_p50_ms") or 100.0),
                viewer_token="" if args.observer_viewer else token,
            )
            row["link"] = {
                "profile": name,
                "backend": pair.backend or "none",
                **link.figures(),
                **dense_figures(dense),
            }
            row["goals"] = goals(name, row)
            row["profile_wall_s"] = time.monotonic() - profile_started
            row["link_measure_s"] = measured_s
            figures[name] = row
            print(f"-- {name}: {profile}")
            for k, v in row.items():
                if not isinstance(v, dict | list):
                    print(f"  {k:<36} {v:.4g}" if isinstance(v, float) else f"  {k:<36} {v}")
            if chromium := row.get("chromium"):
                print(f"  chromium {_brief(chromium)}")
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
        "viewer": args.viewer,
        "viewers_as": "observer" if args.observer_viewer else "operator",
        "wall_s": time.monotonic() - started,
        "machine": machine(),
    }
    print(f"wall time {summary['wall_s']:.0f} s")
    if args.json:
        print(json.dumps({**figures, **summary}))


if __name__ == "__main__":
    main()
