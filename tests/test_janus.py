"""Janus, a real process, as the media server (issue 18, groundwork): started with the
configuration we generate, fed the encoder's own H.264 packets as RTP (no second
encode), watched by an aiortc viewer through its HTTP API, which decodes the picture's
timecode; killed and started again, the viewer comes back."""

from __future__ import annotations

import asyncio
import secrets
import shutil
import threading
import time

import numpy as np
import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription

from backend.media.encoder import H264Encoder
from backend.media.janus import JanusProcess, JanusSettings, JanusViewer, RtpFeed, free_port
from drivers.base import StereoFrame
from drivers.camera import timecode

WIDTH, HEIGHT, FPS = 1280, 360, 30.0  # side by side: two 640×360 eyes (the timecode needs 520 px)


@pytest.fixture
def settings() -> JanusSettings:
    if shutil.which("janus") is None:
        pytest.fail("Debian's janus is missing: `make test` installs it")
    import socket

    return JanusSettings(
        http_port=free_port(), rtp_port=free_port(socket.SOCK_DGRAM), secret=secrets.token_hex(8)
    )


class Feed:
    """The robot's side: frames with a timecode, encoded once, sent as RTP at 30 fps."""

    def __init__(self, port: int) -> None:
        self.encoder = H264Encoder(WIDTH, HEIGHT, FPS, 1_000_000, keyframe_interval=1.0)
        self.rtp = RtpFeed(port)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self) -> None:
        seq = 0
        while not self.stop.wait(1 / FPS):
            now = time.monotonic()
            image = np.full((HEIGHT, WIDTH, 3), 90, np.uint8)
            timecode.draw(image[:, : WIDTH // 2], now)
            for encoded in self.encoder.encode(StereoFrame(seq, now, image)):
                self.rtp.send(encoded.packet)
            seq += 1

    def __enter__(self) -> Feed:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(2)
        self.rtp.close()


async def watch(settings: JanusSettings, frames: int = 10) -> tuple[list[float], int]:
    """An aiortc viewer through Janus: the capture → decoded age of ``frames`` frames,
    and the viewer count Janus reported meanwhile."""
    viewer = await asyncio.to_thread(JanusViewer, settings.api)
    pc = RTCPeerConnection()
    try:
        offer = await asyncio.to_thread(viewer.watch)
        tracks: asyncio.Queue[object] = asyncio.Queue()
        pc.on("track", tracks.put_nowait)
        await pc.setRemoteDescription(RTCSessionDescription(offer["sdp"], offer["type"]))
        await pc.setLocalDescription(await pc.createAnswer())
        await asyncio.to_thread(viewer.start, pc.localDescription.sdp)
        track = await asyncio.wait_for(tracks.get(), 15)
        ages: list[float] = []
        while len(ages) < frames:
            frame = await asyncio.wait_for(track.recv(), 15)  # type: ignore[attr-defined]
            luma = frame.to_ndarray()[: frame.height, : frame.width // 2]
            code = timecode.read(luma)
            if code is not None:
                ages.append(timecode.elapsed(code, time.monotonic()))
        viewers = int((await asyncio.to_thread(viewer.info, settings.secret))["viewers"])
        return ages, viewers
    finally:
        await pc.close()
        await asyncio.to_thread(viewer.close)


def test_viewers_through_janus_decode_the_timecode_of_the_one_encoded_stream(
    settings: JanusSettings,
) -> None:
    with JanusProcess(settings) as janus, Feed(settings.rtp_port) as feed:
        assert janus.alive
        ages, viewers = asyncio.run(watch(settings))
        assert viewers == 1
        assert len(ages) == 10 and 0 < float(np.median(ages)) < 0.5, ages
        assert feed.rtp.packets > 0 and feed.encoder.frames > 0


def test_janus_killed_and_started_again_serves_the_next_viewer(settings: JanusSettings) -> None:
    janus = JanusProcess(settings).start()
    try:
        with Feed(settings.rtp_port):
            asyncio.run(watch(settings, frames=3))
            assert janus.proc is not None
            janus.proc.kill()
            janus.proc.wait(5)
            assert not janus.alive
            janus.stop()
            janus.start()  # the same ports, a fresh configuration
            ages, _ = asyncio.run(watch(settings, frames=3))
            assert len(ages) == 3
    finally:
        janus.stop()
