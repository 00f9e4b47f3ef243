"""Stereo video at 2×1280×720, 30 fps: our WebRTC pipeline against two baselines.

    python -m bench.video [--json] [--seconds 60]

* **ours**: ``telerobot serve`` (simulated camera, media worker, one H.264 encoder)
  with the arm moving; a viewer in a separate process (aiortc) decodes every frame
  and reads the capture time from the picture's timecode: fps, capture → decoded
  latency. Encode time from the server's video telemetry. Server CPU (server +
  media worker) with 1 viewer, then with 5 (the 4 extra receive without decoding).
* **bmp_tcp**: the thesis's scheme: raw bitmaps over TCP, one request per frame.
* **jpeg_ws**: JPEG frames pushed over a WebSocket (what several XR teleop projects do).
The baselines render the same scene with the same camera code, in their own process.
"""

from __future__ import annotations

import asyncio
import contextlib
import multiprocessing
import os
import secrets
import socket
import struct
import threading
import time
from typing import Any

import httpx
import numpy as np
import psutil

from bench.common import emit, machine, parser
from harness.aiortc_viewers import open_viewer
from harness.servers import serve_for_bench

WIDTH, HEIGHT, FPS = 1280, 720, 30.0


# ---------------------------------------------------------------- viewers (own process)
def _disable_decoding() -> None:
    """Passive viewers receive and acknowledge RTP like a browser but skip decoding,
    so that five viewers on this 2-core machine measure the server, not the viewers."""
    import aiortc.rtcrtpreceiver as receiver

    class NullDecoder:
        def decode(self, encoded_frame: Any) -> list[Any]:
            return []

    receiver.get_decoder = lambda codec: NullDecoder()  # type: ignore[assignment]


def _note_last_packets(arrivals: dict[int, float]) -> None:
    """Record when the last RTP packet (marker bit) of each frame arrives. aiortc's
    jitter buffer only releases a frame when the next frame's first packet arrives
    (one frame interval later); browsers use the marker bit and do not wait."""
    import aiortc.rtcrtpreceiver as receiver

    original = receiver.RTCRtpReceiver._handle_rtp_packet

    async def handle(self: Any, packet: Any, arrival_time_ms: int) -> None:
        arrivals.setdefault(-1, packet.timestamp)  # the receiver counts pts from here
        if packet.marker:
            arrivals[packet.timestamp] = time.monotonic()
        await original(self, packet, arrival_time_ms)

    receiver.RTCRtpReceiver._handle_rtp_packet = handle  # type: ignore[method-assign]


async def _viewer(base: str, decode: bool, seconds: float, out: dict[str, Any]) -> None:
    from telerobot.drivers.camera import timecode

    pc, track = await open_viewer(base)
    if not decode:
        await asyncio.sleep(seconds)
        await pc.close()
        return
    last_packets: dict[int, float] = {}
    _note_last_packets(last_packets)
    latencies, arrivals, to_last_packet = [], [], []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        frame = await asyncio.wait_for(track.recv(), 10)
        now = time.monotonic()
        rgb = frame.to_ndarray(format="rgb24")
        code = timecode.read(rgb[:, : rgb.shape[1] // 2])
        if code is not None:
            age = timecode.elapsed(code, now)
            latencies.append(age)
            arrivals.append(now)
            rtp = (last_packets.get(-1, 0) + frame.pts) % (1 << 32)
            if rtp in last_packets:
                to_last_packet.append(age - (now - last_packets.pop(rtp)))
    out["latencies"], out["arrivals"], out["to_last_packet"] = latencies, arrivals, to_last_packet
    await pc.close()


def run_viewers(base: str, decode: int, passive: int, seconds: float, queue: Any) -> None:
    if passive and not decode:
        _disable_decoding()

    async def main() -> None:
        results: list[dict[str, Any]] = [{} for _ in range(decode + passive)]
        await asyncio.gather(
            *(_viewer(base, i < decode, seconds, results[i]) for i in range(decode + passive))
        )
        queue.put(results[0] if decode else {})

    asyncio.run(main())


# ---------------------------------------------------------------- ours
def _cpu_seconds(pid: int) -> float:
    proc = psutil.Process(pid)
    total = 0.0
    for p in [proc, *proc.children(recursive=True)]:
        with contextlib.suppress(psutil.NoSuchProcess):
            t = p.cpu_times()
            total += t.user + t.system
    return total


def _drive_arm(base: str, token: str, stop: threading.Event) -> None:
    """Keep the simulated arm moving so the frames change as they would in use."""
    h = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=base, timeout=30) as http:
        h["X-Client-Id"] = http.post("api/v1/lease", json={"name": "bench"}, headers=h).json()[
            "client_id"
        ]
        poses = ([0.4, 0.6, -2.8, 0.3, 0.6, 0.5], [-0.3, 0.9, -3.0, -0.3, 0.9, -0.5])
        i = 0
        while not stop.is_set():
            http.post(
                "api/v1/robot/move",
                json={"space": "joint", "mode": "absolute", "joints": poses[i % 2]},
                headers=h,
            )
            i += 1


def measure_ours(seconds: float) -> dict[str, Any]:
    ctx = multiprocessing.get_context("spawn")
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_VIDEO": "true",
        "TELEROBOT_VIDEO_WIDTH": str(WIDTH),
        "TELEROBOT_VIDEO_HEIGHT": str(HEIGHT),
        "TELEROBOT_VIDEO_FPS": str(FPS),
        "TELEROBOT_OPERATOR_TOKEN": token,
    }
    with serve_for_bench(env=env) as (proc, base):
        time.sleep(5)  # the arm initialises, the media worker starts
        stop = threading.Event()
        driver = threading.Thread(target=_drive_arm, args=(base, token, stop), daemon=True)
        driver.start()
        queue = ctx.Queue()
        one = ctx.Process(target=run_viewers, args=(base, 1, 0, seconds, queue))
        one.start()
        time.sleep(min(10.0, seconds / 4))  # settle
        window = min(20.0, seconds / 3)
        c0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(window)
        cpu_1 = (_cpu_seconds(proc.pid) - c0) / (time.monotonic() - t0)
        result = queue.get(timeout=seconds + 60)
        one.join()
        # Five viewers: the decoding one plus four passive ones.
        five_q = ctx.Queue()
        extra = ctx.Process(target=run_viewers, args=(base, 0, 4, window + 15, five_q))
        again = ctx.Process(target=run_viewers, args=(base, 1, 0, window + 15, queue))
        extra.start()
        again.start()
        time.sleep(10)
        c0, t0 = _cpu_seconds(proc.pid), time.monotonic()
        time.sleep(window)
        cpu_5 = (_cpu_seconds(proc.pid) - c0) / (time.monotonic() - t0)
        status = httpx.get(base + "api/v1/video", timeout=10).json()
        five_q.get(timeout=60)
        queue.get(timeout=60)
        extra.join()
        again.join()
        stop.set()
    lat = np.array(result["latencies"]) * 1000
    last = np.array(result["to_last_packet"]) * 1000
    arrivals = np.array(result["arrivals"])
    fps = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
    stats = status["stats"]
    return {
        "fps": float(fps),
        "encode_p50_ms": stats["encode_ms_p50"],
        "encode_p99_ms": stats["encode_ms_p99"],
        "latency_p50_ms": float(np.percentile(lat, 50)),
        "latency_p99_ms": float(np.percentile(lat, 99)),
        "frames": len(lat),
        "capture_to_last_packet_p50_ms": float(np.percentile(last, 50)) if len(last) else None,
        "capture_to_last_packet_p99_ms": float(np.percentile(last, 99)) if len(last) else None,
        "cpu_1_viewer": cpu_1,
        "cpu_5_viewers": cpu_5,
        "cpu_ratio_5_vs_1": cpu_5 / cpu_1,
        "bytes_per_frame": stats["bytes_per_frame_mean"],
        "mbps": stats["bytes_per_frame_mean"] * 8 * fps / 1e6,
        "keyframe_bytes": stats["keyframe_bytes_last"],
        "viewers_seen_by_server": len(stats["viewers"]),
    }


# ---------------------------------------------------------------- baselines (own process)
def _camera() -> Any:
    from telerobot.drivers.base import ArmSnapshot
    from telerobot.drivers.camera.sim import SimStereoCamera
    from telerobot.drivers.robot.puma560.kinematics import (
        NAMED_POSES,
        Puma560Kinematics,
        tool_transform,
    )
    from telerobot.drivers.sim.workcell import default_workcell

    start = time.monotonic()

    def probe() -> ArmSnapshot:  # the same swinging arm, computed
        t = time.monotonic() - start
        q = NAMED_POSES["qn"] + 0.4 * np.sin(t) * np.array([1, 0.5, 0.3, 1, 0.5, 1])
        return ArmSnapshot(time.monotonic(), q, np.zeros(6))

    return SimStereoCamera(
        default_workcell(width=WIDTH, height=HEIGHT),
        probe,
        Puma560Kinematics(tool_transform(0.1)),
        fps=FPS,
    )


def serve_bmp_tcp(port_queue: Any) -> None:
    """The thesis's server: on each request, grab a frame and send it as a bitmap."""
    import cv2

    cam = _camera()
    server = socket.create_server(("127.0.0.1", 0))
    port_queue.put(server.getsockname()[1])
    conn, _ = server.accept()
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    with contextlib.suppress(OSError):
        while conn.recv(1):
            frame = cam.capture()
            _, bmp = cv2.imencode(".bmp", cv2.cvtColor(frame.sbs, cv2.COLOR_RGB2BGR))
            data = bmp.tobytes()
            conn.sendall(struct.pack("<I", len(data)) + data)


def serve_jpeg_ws(port_queue: Any) -> None:
    """Push the newest frame as a JPEG to the WebSocket client, at the capture rate."""
    import cv2
    import websockets

    cam = _camera()
    cam.start()

    async def handler(ws: Any) -> None:
        seq = 0
        loop = asyncio.get_running_loop()
        with contextlib.suppress(websockets.ConnectionClosed):
            while True:
                frame = await loop.run_in_executor(None, cam.next_frame, seq, 1.0)
                if frame is None:
                    continue
                seq = frame.seq
                _, jpg = cv2.imencode(
                    ".jpg",
                    cv2.cvtColor(frame.sbs, cv2.COLOR_RGB2BGR),
                    [cv2.IMWRITE_JPEG_QUALITY, 80],
                )
                await ws.send(jpg.tobytes())

    async def main() -> None:
        async with websockets.serve(
            handler, "127.0.0.1", 0, max_size=None, compression=None
        ) as server:
            port_queue.put(next(iter(server.sockets)).getsockname()[1])
            await asyncio.Future()

    asyncio.run(main())


def _summary(latencies: list[float], arrivals: list[float], nbytes: int) -> dict[str, float]:
    span = arrivals[-1] - arrivals[0]
    return {
        "fps": (len(arrivals) - 1) / span,
        "latency_p50_ms": float(np.percentile(np.array(latencies) * 1000, 50)),
        "latency_p99_ms": float(np.percentile(np.array(latencies) * 1000, 99)),
        "mbps": nbytes * 8 / span / 1e6,
    }


def measure_bmp_tcp(seconds: float) -> dict[str, float]:

    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue()
    server = ctx.Process(target=serve_bmp_tcp, args=(q,), daemon=True)
    server.start()
    sock = socket.create_connection(("127.0.0.1", q.get(timeout=60)))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    latencies, arrivals, nbytes = [], [], 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        sock.sendall(b"G")  # one request per frame, as the thesis's client did
        (size,) = struct.unpack("<I", sock.recv(4, socket.MSG_WAITALL))
        buf = bytearray(size)
        view, got = memoryview(buf), 0
        while got < size:
            got += sock.recv_into(view[got:], size - got)
        _record(buf, latencies, arrivals)
        nbytes += size
    sock.close()
    server.terminate()
    return _summary(latencies, arrivals, nbytes)


def _record(encoded: bytes | bytearray, latencies: list[float], arrivals: list[float]) -> None:
    """Decode a baseline's frame and note its age from the timecode, if readable."""
    import cv2

    from telerobot.drivers.camera import timecode

    img = cv2.imdecode(np.frombuffer(encoded, np.uint8), cv2.IMREAD_COLOR)
    now = time.monotonic()
    code = timecode.read(img[:, :WIDTH])
    if code is not None:
        latencies.append(timecode.elapsed(code, now))
        arrivals.append(now)


def measure_jpeg_ws(seconds: float) -> dict[str, float]:
    import websockets

    ctx = multiprocessing.get_context("spawn")
    q = ctx.Queue()
    server = ctx.Process(target=serve_jpeg_ws, args=(q,), daemon=True)
    server.start()
    port = q.get(timeout=60)

    async def client() -> dict[str, float]:
        latencies, arrivals, nbytes = [], [], 0
        async with websockets.connect(
            f"ws://127.0.0.1:{port}", max_size=None, compression=None
        ) as ws:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                data = await ws.recv()
                _record(data, latencies, arrivals)
                nbytes += len(data)
        return _summary(latencies, arrivals, nbytes)

    try:
        return asyncio.run(client())
    finally:
        server.terminate()


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--seconds", type=float, default=60.0, help="length of our stream's measurement")
    p.add_argument("--baseline-seconds", type=float, default=15.0)
    args = p.parse_args()
    ours = measure_ours(args.seconds)
    baselines = {
        "bmp_tcp": measure_bmp_tcp(args.baseline_seconds),
        "jpeg_ws": measure_jpeg_ws(args.baseline_seconds),
    }
    for b in baselines.values():
        b["latency_ratio_to_ours"] = b["latency_p50_ms"] / ours["latency_p50_ms"]
        b["fps_ratio_to_ours"] = b["fps"] / ours["fps"]
        b["mbps_ratio_to_ours"] = b["mbps"] / ours["mbps"]
    emit({k: v for k, v in ours.items() if not isinstance(v, list)}, False)
    for name, b in baselines.items():
        print(name, " ".join(f"{k}={v:.3g}" for k, v in b.items()))
    if args.json:
        import json

        print(
            json.dumps(
                {**ours, "baselines": baselines, "machine": machine(), "cpus": os.cpu_count()}
            )
        )


if __name__ == "__main__":
    main()
