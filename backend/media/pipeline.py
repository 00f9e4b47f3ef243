"""Camera → one encoder → every WebRTC peer, plus the peers themselves.

Runs inside the media worker process (``backend/media/worker.py``) so that capture,
encoding and packetising can never stall the server's event loop; tests also run it
in-process. Capture and encoding each have a thread of their own; the event loop
only moves packets and talks to peers.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from aiortc import (
    RTCConfiguration,
    RTCIceServer,
    RTCPeerConnection,
    RTCRtpSender,
    RTCSessionDescription,
)

from backend.media.encoder import ENCODERS, EncodedFrame, PacketEncoder
from backend.media.fanout import Broadcaster, SharedVideoTrack
from backend.netprio import mark_peer_low_priority
from backend.telemetry.stats import InterArrival, StreamStats
from drivers.base import CameraStatus, StereoCamera, StereoFrame, TelerobotError

log = logging.getLogger(__name__)


class BadOffer(TelerobotError):
    """The session description cannot be used; the reason says why."""

    code = "bad_offer"


@dataclass(frozen=True)
class VideoSettings:
    fps: float = 30.0
    bitrate: int = 8_000_000
    keyframe_interval: float = 2.0
    cbr: bool = False  # H.264 at constant bitrate (filler data), not "up to"
    ice_servers: tuple[str, ...] = ()  # "stun:host:port" or "turn:user:pass@host:port"


@dataclass
class Peer:
    pc: RTCPeerConnection
    track: SharedVideoTrack
    created: float = field(default_factory=time.monotonic)


def no_signal_frame(width: int, height: int, message: str, seq: int, t: float) -> StereoFrame:
    """What viewers see while a camera is down: grey with the reason, in both eyes."""
    eye = np.full((height, width, 3), 40, np.uint8)
    for i, text in enumerate(("NO SIGNAL", message[:60])):
        scale = 3.0 if i == 0 else 1.2
        (tw, _), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 3)
        cv2.putText(
            eye,
            text,
            ((width - tw) // 2, height // 2 + i * 80),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            (230, 230, 230),
            3,
        )
    return StereoFrame(seq, t, np.concatenate([eye, eye], axis=1))


def _ice(servers: tuple[str, ...]) -> RTCConfiguration:
    parsed = []
    for url in servers:
        scheme, _, rest = url.partition(":")
        if "@" in rest:  # turn:user:pass@host:port
            creds, _, host = rest.rpartition("@")
            user, _, password = creds.partition(":")
            parsed.append(RTCIceServer(urls=f"{scheme}:{host}", username=user, credential=password))
        else:
            parsed.append(RTCIceServer(urls=url))
    return RTCConfiguration(iceServers=parsed)


class VideoPipeline:
    def __init__(self, camera: StereoCamera, settings: VideoSettings | None = None) -> None:
        self.camera = camera
        self.settings = settings or VideoSettings()
        # One encoder per codec in use (H.264; VP8 only while a viewer needs it), each
        # shared by all of that codec's viewers.
        self.encoders: dict[str, PacketEncoder] = {}
        self.broadcasters: dict[str, Broadcaster] = {}
        self.encoder = self._encoder("H264")
        self.peers: dict[str, Peer] = {}
        self._grab = ThreadPoolExecutor(1, thread_name_prefix="video-grab")
        self._encode = ThreadPoolExecutor(1, thread_name_prefix="video-encode")
        self._task: asyncio.Task[None] | None = None
        self.capture_interarrival = InterArrival("video_capture")
        self.encode_ms = StreamStats("video_encode", "ms")
        self.frame_bytes = StreamStats("video_frame_bytes", "B")
        self.keyframe_bytes = StreamStats("video_keyframe_bytes", "B", capacity=100)
        self.frames_encoded = 0
        self._no_signal_seq = 0

    def _encoder(self, codec: str) -> PacketEncoder:
        if codec not in self.encoders:
            s = self.settings
            enc = ENCODERS[codec](
                2 * self.camera.width,
                self.camera.height,
                s.fps,
                s.bitrate,
                s.keyframe_interval,
                cbr=s.cbr,
            )
            self.encoders[codec] = enc
            self.broadcasters[codec] = Broadcaster(enc.request_keyframe)
        return self.encoders[codec]

    @property
    def broadcaster(self) -> Broadcaster:
        return self.broadcasters["H264"]

    @property
    def viewers(self) -> int:
        return sum(b.viewers for b in self.broadcasters.values())

    # ------------------------------------------------------------ capture → encode
    def start(self) -> None:
        self.camera.start()
        self._task = asyncio.create_task(self._run(), name="video-pipeline")

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        await asyncio.gather(*(p.pc.close() for p in self.peers.values()), return_exceptions=True)
        self.peers.clear()
        await asyncio.get_running_loop().run_in_executor(self._grab, self.camera.stop)
        self._grab.shutdown(wait=False)
        self._encode.shutdown(wait=False)

    async def _run(self) -> None:
        loop = asyncio.get_running_loop()
        seq = 0
        while True:
            frame = await loop.run_in_executor(self._grab, self.camera.next_frame, seq, 0.5)
            if frame is None:
                # No frame for 0.5 s: show viewers why, twice a second, until it is back.
                self._no_signal_seq += 1
                frame = no_signal_frame(
                    self.camera.width,
                    self.camera.height,
                    self.camera.status_message,
                    -self._no_signal_seq,
                    time.monotonic(),
                )
            else:
                seq = frame.seq
                self.capture_interarrival.tick(frame.time)
            for codec, broadcaster in list(self.broadcasters.items()):
                if broadcaster.viewers == 0:
                    continue  # nobody watching in this codec: no encoding
                encoder = self.encoders[codec]
                for encoded in await loop.run_in_executor(self._encode, encoder.encode, frame):
                    if codec == "H264":
                        self._record(encoded)
                    broadcaster.publish(encoded)

    def _record(self, e: EncodedFrame) -> None:
        self.frames_encoded += 1
        self.encode_ms.record(e.encode_ms)
        self.frame_bytes.record(e.size)
        if e.keyframe:
            self.keyframe_bytes.record(e.size)

    # ------------------------------------------------------------ signalling
    def _new_peer(self, codec: str = "H264") -> tuple[str, Peer]:
        pc = RTCPeerConnection(_ice(self.settings.ice_servers))
        self._encoder(codec)
        track = self.broadcasters[codec].new_track()
        transceiver = pc.addTransceiver(track, direction="sendonly")
        wanted = f"video/{codec}"
        caps = RTCRtpSender.getCapabilities("video").codecs
        transceiver.setCodecPreferences([c for c in caps if c.mimeType == wanted])
        sender = transceiver.sender
        resend = (
            sender._send_keyframe
        )  # aiortc calls this on PLI/FIR; pre-encoded video needs us to act

        def on_keyframe_request() -> None:
            resend()
            track.keyframe_requested()

        sender._send_keyframe = on_keyframe_request  # type: ignore[method-assign]
        peer_id = secrets.token_hex(8)
        peer = Peer(pc, track)
        self.peers[peer_id] = peer

        @pc.on("connectionstatechange")
        async def on_state() -> None:
            if pc.connectionState == "connected":
                mark_peer_low_priority(pc)  # forces and commands go first
            if pc.connectionState in ("failed", "closed"):
                await self.close_peer(peer_id)

        return peer_id, peer

    async def close_peer(self, peer_id: str) -> None:
        peer = self.peers.pop(peer_id, None)
        if peer is not None:
            peer.track.stop()
            await peer.pc.close()

    async def answer(self, sdp: str, kind: str) -> dict[str, str]:
        """The browser offers, we answer (the usual way)."""
        if kind != "offer":
            raise BadOffer(f"expected an SDP of type 'offer', got {kind!r}")
        if "m=video" not in sdp:
            raise BadOffer("the offer has no video section: add a recvonly video transceiver")
        upper = sdp.upper()
        if "H264" in upper:
            codec = "H264"
        elif "VP8" in upper:
            codec = "VP8"  # the fallback: a second encoder, only while such viewers watch
        else:
            raise BadOffer("the offer accepts neither H.264 nor VP8 video")
        peer_id, peer = self._new_peer(codec)
        try:
            await peer.pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="offer"))
            await peer.pc.setLocalDescription(await peer.pc.createAnswer())
        except Exception as exc:
            await self.close_peer(peer_id)
            raise BadOffer(f"cannot use this offer: {exc}") from None
        local = peer.pc.localDescription
        return {"peer_id": peer_id, "sdp": local.sdp, "type": local.type}

    async def offer(self) -> dict[str, str]:
        """We offer (for browsers that need the server to): answer with ``accept``."""
        peer_id, peer = self._new_peer()
        await peer.pc.setLocalDescription(await peer.pc.createOffer())
        local = peer.pc.localDescription
        return {"peer_id": peer_id, "sdp": local.sdp, "type": local.type}

    async def accept(self, peer_id: str, sdp: str, kind: str) -> dict[str, str]:
        peer = self.peers.get(peer_id)
        if peer is None:
            raise BadOffer(f"no pending offer {peer_id!r} (it may have expired)")
        if kind != "answer":
            raise BadOffer(f"expected an SDP of type 'answer', got {kind!r}")
        try:
            await peer.pc.setRemoteDescription(RTCSessionDescription(sdp=sdp, type="answer"))
        except Exception as exc:
            await self.close_peer(peer_id)
            raise BadOffer(f"cannot use this answer: {exc}") from None
        return {"peer_id": peer_id}

    # ------------------------------------------------------------ telemetry
    def stats(self) -> dict[str, Any]:
        cap = self.capture_interarrival.summary()
        enc = self.encode_ms.summary()
        size = self.frame_bytes.summary()
        keys = self.keyframe_bytes.values()
        now = time.monotonic()
        return {
            "camera": {
                "name": self.camera.name,
                "status": self.camera.status.value,
                "message": self.camera.status_message,
            },
            "capture_fps": 1000.0 / cap.mean if cap.count and cap.mean > 0 else None,
            "encode_ms_p50": enc.p50 if enc.count else None,
            "encode_ms_p99": enc.p99 if enc.count else None,
            "bytes_per_frame_mean": size.mean if size.count else None,
            "keyframe_bytes_last": keys[-10:].tolist(),
            "frames_encoded": self.frames_encoded,
            "codecs": {codec: b.viewers for codec, b in self.broadcasters.items()},
            "viewers": [
                {
                    "peer_id": pid,
                    "state": p.pc.connectionState,
                    "frames": p.track.sent_frames,
                    "bytes": p.track.sent_bytes,
                    "mbps": p.track.sent_bytes * 8 / 1e6 / max(now - p.created, 1e-3),
                    "resyncs": p.track.resyncs,
                }
                for pid, p in self.peers.items()
            ],
            "camera_running": self.camera.status is CameraStatus.RUNNING,
        }
