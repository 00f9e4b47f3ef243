"""Janus, a real process, as the media server: started with the
configuration we generate, fed the encoder's own H.264 packets as RTP (no second
encode), watched by an aiortc viewer through its HTTP API, which decodes the picture's
timecode; killed and started again, the viewer comes back."""

from __future__ import annotations

import asyncio
import contextlib
import json
import secrets
import shutil
import threading
import time
from typing import Any

import httpx
import numpy as np
import pytest
from aiortc import RTCPeerConnection, RTCSessionDescription

from telerobot.drivers.base import DeviceError, StereoFrame
from telerobot.drivers.camera import timecode
from telerobot.server.media.encoder import H264Encoder
from telerobot.server.media.janus import MOUNTPOINT, JanusProcess, JanusSettings, RtpFeed, free_port

WIDTH, HEIGHT, FPS = 1280, 360, 30.0  # side by side: two 640×360 eyes (the timecode needs 520 px)


class JanusViewer:
    """One viewer's session on the streaming plugin (HTTP API): ``watch`` gives Janus's
    SDP offer, ``start`` takes the answer, ``close`` destroys the session. Janus ends a
    session ~60 s after its last request, watching or not: one kept open must poll."""

    def __init__(self, api: str, timeout_s: float = 10.0, api_secret: str | None = None) -> None:
        self.api = api
        self._secret = {"apisecret": api_secret} if api_secret else {}
        self.http = httpx.Client(timeout=timeout_s + 5)
        self.timeout_s = timeout_s
        self._n = 0
        self.session = self._post(api, {"janus": "create"})["data"]["id"]
        url = f"{api}/{self.session}"
        self.handle = self._post(url, {"janus": "attach", "plugin": "janus.plugin.streaming"})[
            "data"
        ]["id"]

    def _post(self, url: str, body: dict[str, Any]) -> dict[str, Any]:
        self._n += 1
        reply: dict[str, Any] = self.http.post(
            url, json={**body, **self._secret, "transaction": str(self._n)}
        ).json()
        if reply.get("janus") == "error":
            raise DeviceError(f"janus: {reply.get('error', {}).get('reason', reply)}")
        return reply

    def message(self, body: dict[str, Any], jsep: dict[str, Any] | None = None) -> dict[str, Any]:
        payload: dict[str, Any] = {"janus": "message", "body": body}
        if jsep is not None:
            payload["jsep"] = jsep
        return self._post(f"{self.api}/{self.session}/{self.handle}", payload)

    def watch(self, mountpoint: int = MOUNTPOINT) -> dict[str, Any]:
        """Janus's SDP offer for the mountpoint (``{"type": "offer", "sdp": …}``)."""
        self.message({"request": "watch", "id": mountpoint})
        deadline = time.monotonic() + self.timeout_s
        while time.monotonic() < deadline:
            params = {"maxev": "5", **self._secret}
            events = self.http.get(f"{self.api}/{self.session}", params=params).json()
            for event in events if isinstance(events, list) else [events]:
                if "jsep" in event:
                    jsep: dict[str, Any] = event["jsep"]
                    return jsep
        raise DeviceError(f"janus sent no offer within {self.timeout_s:g} s")

    def start(self, answer_sdp: str) -> None:
        # aiortc puts its candidates in the answer: no trickle to wait for.
        self.message({"request": "start"}, {"type": "answer", "sdp": answer_sdp, "trickle": False})

    def info(self, secret: str, mountpoint: int = MOUNTPOINT) -> dict[str, Any]:
        reply = self.message({"request": "info", "id": mountpoint, "secret": secret})
        info: dict[str, Any] = reply["plugindata"]["data"]["info"]
        return info

    def close(self) -> None:
        with contextlib.suppress(httpx.HTTPError, DeviceError, json.JSONDecodeError):
            self._post(f"{self.api}/{self.session}", {"janus": "destroy"})
        self.http.close()


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


def test_rtp_timestamps_wrap_on_a_machine_up_more_than_13_hours() -> None:
    # The feed's RTP timestamp is the capture time (monotonic, since boot) at 90 kHz:
    # at 13.25 h of uptime it passed 2³², every send raised in the feed's thread and
    # the relay's viewers got no frame. It wraps, as RTP's 32 bits do.
    import socket

    from aiortc.rtp import RtpPacket

    sink = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sink.bind(("127.0.0.1", 0))
    sink.settimeout(5)
    feed = RtpFeed(sink.getsockname()[1])
    encoder = H264Encoder(64, 64, FPS, 200_000, keyframe_interval=1.0)
    uptime = 50_000.0  # s: 4.5·10⁹ ticks of 90 kHz
    try:
        packets = []
        for n in range(3):
            image = np.full((64, 64, 3), 90, np.uint8)
            packets += encoder.encode(StereoFrame(n, uptime + n / FPS, image))
        assert packets
        for encoded in packets:
            feed.send(encoded.packet)
        got = RtpPacket.parse(sink.recv(2048))
        assert got.timestamp == round(uptime * 90_000) & 0xFFFFFFFF
    finally:
        feed.close()
        sink.close()
