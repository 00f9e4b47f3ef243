"""One H.264 encoder for every viewer (PyAV / libx264).

Low-latency settings: ``ultrafast`` preset, ``zerolatency`` tune (no lookahead, no
frame threads' delay), no B-frames, a VBV cap so a keyframe cannot flood the link, a
keyframe whenever someone asks (a new peer, a PLI, a NACK the sender cannot serve, a
recording) and, if ``keyframe_interval`` > 0, every that many seconds too. None
periodic by default, as libwebrtc sends none: a keyframe is tens of frames' bytes in
one burst, and on a narrow link (4 Mbit/s) each periodic one queued everything behind
it, the forces included, for ~250 ms (docs/PERFORMANCE.md, "Key frames only when
asked"). The level is chosen for the frame size (2560×720 needs level 4.0, beyond the
3.1 WebRTC stacks default to). Timestamps come from the capture time (90 kHz).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, cast

import av
import cv2
import numpy as np
from av.video.codeccontext import VideoCodecContext

from telerobot.drivers.base import StereoFrame

VIDEO_CLOCK = 90_000
# The VBV buffer, in time at the bitrate: what a key frame (or a burst of motion) can put
# on the link at once, so the queue it makes behind it stays this short at any frame
# rate (4 frames at 30 fps, as it was measured; 8 at 60: a frame's own share of the
# bitrate halves at 60 fps, its key frames' bound does not).
VBV_S = 4 / 30


def h264_level(width: int, height: int, fps: float) -> str:
    """The lowest H.264 level whose frame size and macroblock rate fit."""
    mbs = ((width + 15) // 16) * ((height + 15) // 16)
    for level, max_fs, max_mbps in (
        ("3.1", 3600, 108_000),
        ("3.2", 5120, 216_000),
        ("4.0", 8192, 245_760),
        ("4.2", 8704, 522_240),
        ("5.1", 36_864, 983_040),
    ):
        if mbs <= max_fs and mbs * fps <= max_mbps:
            return level
    return "5.1"


@dataclass(frozen=True)
class EncodedFrame:
    packet: Any  # av.Packet, handed to aiortc as is
    keyframe: bool
    size: int
    capture_time: float
    seq: int
    encode_ms: float


class PacketEncoder:
    """Encodes ``StereoFrame``s into packets that aiortc sends as they are."""

    codec = ""  # the SDP name: "H264", "VP8"
    library = ""  # the FFmpeg encoder

    def __init__(
        self,
        width: int,
        height: int,
        fps: float,
        bitrate: int,
        keyframe_interval: float = 0.0,  # s; 0: only when asked
        cbr: bool = False,
    ) -> None:
        self.width, self.height, self.fps, self.bitrate = width, height, fps, bitrate
        self.cbr = cbr
        ctx = cast(VideoCodecContext, av.CodecContext.create(self.library, "w"))
        ctx.width, ctx.height = width, height
        ctx.pix_fmt = "yuv420p"
        ctx.time_base = Fraction(1, VIDEO_CLOCK)
        ctx.framerate = Fraction(round(fps * 1000), 1000)
        ctx.bit_rate = bitrate
        periodic = keyframe_interval > 0
        ctx.options = self.options(max(1, round(keyframe_interval * fps)) if periodic else None)
        ctx.open()
        self.ctx = ctx
        self._keyframe = threading.Event()
        self._keyframe.set()  # the first frame is one anyway
        self.frames = 0
        self._new_bitrate: int | None = None

    def options(self, keyint: int | None) -> dict[str, str]:
        """The FFmpeg options; ``keyint``: frames between periodic keyframes (None: none)."""
        raise NotImplementedError

    def request_keyframe(self) -> None:
        self._keyframe.set()

    def set_bitrate(self, bps: int) -> None:
        """A new average bitrate from the next frame on, at most the one it was opened
        with (its VBV cap): libx264 takes it without a key frame (FFmpeg reconfigures
        x264 when ``bit_rate`` changes, as long as the VBV was set through the codec
        context's own maxrate and bufsize). Taken by ``encode``, on the encoder's thread."""
        self._new_bitrate = max(1000, min(int(bps), self.bitrate))

    def encode(self, frame: StereoFrame) -> list[EncodedFrame]:
        started = time.perf_counter()
        yuv = cast(
            "np.ndarray[Any, np.dtype[np.uint8]]",
            cv2.cvtColor(np.ascontiguousarray(frame.sbs), cv2.COLOR_RGB2YUV_I420),
        )
        video = av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        video.pts = round(frame.time * VIDEO_CLOCK)
        video.time_base = Fraction(1, VIDEO_CLOCK)
        if (bps := self._new_bitrate) is not None:
            self._new_bitrate = None
            self.ctx.bit_rate = bps
        if self._keyframe.is_set():
            self._keyframe.clear()
            video.pict_type = av.video.frame.PictureType.I
        out = []
        for packet in self.ctx.encode(video):
            packet.time_base = Fraction(1, VIDEO_CLOCK)
            out.append(
                EncodedFrame(
                    packet,
                    bool(packet.is_keyframe),
                    packet.size,
                    frame.time,
                    frame.seq,
                    (time.perf_counter() - started) * 1000,
                )
            )
        self.frames += 1
        return out


class H264Encoder(PacketEncoder):
    codec, library = "H264", "libx264"

    def options(self, keyint: int | None) -> dict[str, str]:
        kbps = self.bitrate // 1000
        # VBV: at most VBV_S of the bitrate in flight, so a keyframe stays bounded.
        bufsize = max(round(kbps * VBV_S), 1)
        return {
            "preset": "ultrafast",
            "tune": "zerolatency",
            "profile": "baseline",
            "level": h264_level(self.width, self.height, self.fps),
            # The VBV through the codec context (not x264-params), so that a new
            # bit_rate later is taken (set_bitrate; FFmpeg's libx264 wrapper compares
            # the context's maxrate and bufsize with x264's before it reconfigures).
            "maxrate": f"{kbps}k",
            "bufsize": f"{bufsize}k",
            "x264-params": (
                f"keyint={keyint}:min-keyint={keyint}:" if keyint else "keyint=infinite:"
            )
            + "bframes=0:scenecut=0:repeat-headers=1"
            # Constant bitrate: filler data tops every second up to the bitrate (a fixed
            # link budget, and the load the force-under-video benchmark needs).
            + (":nal-hrd=cbr:filler=1" if self.cbr else ""),
        }


class Vp8Encoder(PacketEncoder):
    """The fallback for viewers without H.264: libvpx in real-time mode, no lag."""

    codec, library = "VP8", "libvpx"

    def options(self, keyint: int | None) -> dict[str, str]:
        return {
            "deadline": "realtime",
            "cpu-used": "8",
            "lag-in-frames": "0",
            "error-resilient": "1",
            "auto-alt-ref": "0",
            # libvpx's kf_max_dist; with no periodic keyframe, as far as it goes
            "g": str(keyint or 2**31 - 1),
        }


ENCODERS: dict[str, type[PacketEncoder]] = {"H264": H264Encoder, "VP8": Vp8Encoder}
