"""Video through the real server: signalling over HTTP to the media worker process,
a real aiortc viewer, and the video API's errors."""

from __future__ import annotations

import asyncio
import time

import httpx
import pytest

from bench.common import open_viewer
from drivers.camera import timecode
from tests.servers import telerobot

URL = r"(http://localhost:\d+/)"
SMALL = {"TELEROBOT_VIDEO": "true", "TELEROBOT_VIDEO_WIDTH": "640", "TELEROBOT_VIDEO_HEIGHT": "360"}


async def receive(base: str, frames: int) -> tuple[list[object], dict[str, object]]:
    """A viewer over real HTTP signalling: decoded RGB frames and the video status."""
    pc, track = await open_viewer(base, timeout=20)
    async with httpx.AsyncClient(base_url=base, timeout=30) as http:
        out = []
        for _ in range(frames):
            frame = await asyncio.wait_for(track.recv(), 20)  # type: ignore[attr-defined]
            out.append((frame.to_ndarray(format="rgb24"), time.monotonic()))
        status = (await http.get("api/v1/video")).json()
        telemetry = (await http.get("api/v1/telemetry")).json()
        assert telemetry["video"]["frames_encoded"] > 0 and telemetry["video"]["encode_ms_p50"] > 0
    await pc.close()
    return out, status


async def watch(base: str, frames: int) -> list[float]:
    received, status = await receive(base, frames)
    ages = []
    for rgb, at in received:
        code = timecode.read(rgb[:, : rgb.shape[1] // 2])  # type: ignore[index]
        assert code is not None
        ages.append(timecode.elapsed(code, at))  # type: ignore[arg-type]
    assert status["worker_alive"] and status["stats"]["frames_encoded"] >= frames  # type: ignore[index]
    assert status["stats"]["viewers"], status  # type: ignore[index]
    return ages


def test_a_browser_like_viewer_gets_the_stream_from_the_media_worker() -> None:
    with telerobot("serve", "--http-port", "0", wait_for=URL, env=SMALL) as (_, m):
        ages = asyncio.run(watch(m.group(1), 30))
    assert sorted(ages)[len(ages) // 2] < 0.5  # capture → decoded, on loopback


def test_video_api_errors_and_alignment() -> None:
    with telerobot("serve", "--http-port", "0", wait_for=URL, env=SMALL) as (_, m):
        base = m.group(1)
        r = httpx.post(
            base + "api/v1/webrtc/offer", json={"sdp": "v=0\r\n", "type": "offer"}, timeout=30
        )
        assert r.status_code == 400 and "no video section" in r.json()["detail"]
        r = httpx.post(
            base + "api/v1/webrtc/answer",
            json={"peer_id": "nope", "sdp": "x", "type": "answer"},
            timeout=30,
        )
        assert r.status_code == 400 and "no pending offer" in r.json()["detail"]
        r = httpx.post(base + "api/v1/webrtc/server-offer", timeout=30)
        assert r.status_code == 200 and r.json()["type"] == "offer" and "H264" in r.json()["sdp"]
        assert httpx.get(base + "api/v1/video/alignment?viewer=alice").json() == {"dx": 0, "dy": 0}
        assert (
            httpx.put(
                base + "api/v1/video/alignment?viewer=alice", json={"dx": 4, "dy": -2}
            ).status_code
            == 200
        )
        assert httpx.get(base + "api/v1/video/alignment?viewer=alice").json() == {"dx": 4, "dy": -2}
        assert httpx.get(base + "api/v1/video/alignment?viewer=bob").json() == {"dx": 0, "dy": 0}
        assert (
            httpx.put(base + "api/v1/video/alignment?viewer=alice", json={"dx": 9999}).status_code
            == 422
        )


def test_video_off_says_so() -> None:
    with telerobot("serve", "--http-port", "0", wait_for=URL) as (_, m):
        r = httpx.post(m.group(1) + "api/v1/webrtc/server-offer", timeout=30)
        assert r.status_code == 503 and "video is turned off" in r.json()["detail"]


@pytest.mark.parametrize("camera", ["opencv"])
def test_a_missing_real_camera_shows_no_signal_and_the_server_keeps_serving(camera: str) -> None:
    env = {
        **SMALL,
        "TELEROBOT_CAMERA": camera,
        "TELEROBOT_CAMERA_DEVICES": '["/dev/video-none-0", "/dev/video-none-1"]',
    }
    with telerobot("serve", "--http-port", "0", wait_for=URL, env=env) as (_, m):
        base = m.group(1)
        deadline = time.monotonic() + 20
        while True:
            status = httpx.get(base + "api/v1/video", timeout=10).json()
            if status["stats"] and status["stats"]["camera"]["status"] == "FAILED":
                break
            assert time.monotonic() < deadline, status
            time.sleep(0.2)
        assert "cannot open camera" in status["stats"]["camera"]["message"]
        received, _ = asyncio.run(receive(base, 2))
        rgb = received[-1][0]
        assert 30 < rgb.mean() < 90  # type: ignore[union-attr]  # the grey NO SIGNAL card
        assert httpx.get(base + "api/v1/health").json()["status"] == "ok"


def test_a_crashed_media_worker_is_restarted_and_control_never_stops() -> None:
    import psutil

    with telerobot("serve", "--http-port", "0", wait_for=URL, env=SMALL) as (proc, m):
        base = m.group(1)
        deadline = time.monotonic() + 30
        while not httpx.get(base + "api/v1/video", timeout=10).json()["worker_alive"]:
            assert time.monotonic() < deadline
            time.sleep(0.2)
        workers = [
            p for p in psutil.Process(proc.pid).children() if "spawn_main" in " ".join(p.cmdline())
        ]
        assert workers, "no media worker process"
        # Video yields the CPU to forces and control (setting video_nice, default 10).
        assert {w.nice() for w in workers} == {10}
        assert psutil.Process(proc.pid).nice() == 0
        for w in workers:
            w.kill()
        assert (
            httpx.get(base + "api/v1/robot/state", timeout=5).status_code == 200
        )  # control keeps serving
        while True:  # the status answers all along, the restart included
            reply = httpx.get(base + "api/v1/video", timeout=10)
            assert reply.status_code == 200, reply.text
            status = reply.json()
            if status["worker_restarts"] >= 1 and status["worker_alive"]:
                break
            assert time.monotonic() < deadline + 30, status
            time.sleep(0.2)
        asyncio.run(watch(base, 5))  # and the stream is back
