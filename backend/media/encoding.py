"""Capture → encode, the video pipeline's producing half (pipeline.py is the peers'):
the camera read on a thread of its own, each frame encoded on another in every codec
and layer someone takes, one encoder per codec and layer in use each with the
``Broadcaster`` that fans its packets out to the viewers' tracks, the taps on the
full layer's H.264 (the recording, the media server's feed), and the figures of all
that.

Apart from the peers because it knows no viewer: it encodes for the broadcasters'
tracks, whoever holds them; the peers (signalling, their limits, their links) pick a
codec and layer here (``encoder_for``, ``broadcasters``) and nothing else."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from telerobot.drivers.base import CameraStatus, StereoCamera, StereoFrame
from telerobot.drivers.clock import Clock
from telerobot.server.media.encoder import ENCODERS, EncodedFrame, PacketEncoder
from telerobot.server.media.fanout import Broadcaster
from telerobot.server.media.frame_rate import FrameRateRule
from telerobot.server.media.layers import LAYERS, OPERATOR, Layer, RateMeter, low_size
from telerobot.server.media.rate_control import RateControl
from telerobot.server.telemetry.stats import InterArrival, StreamStats

if TYPE_CHECKING:
    from telerobot.server.media.pipeline import VideoSettings

log = logging.getLogger(__name__)

IDLE_POLL_S = 0.05  # with no viewer, how often the pipeline looks for one


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


class Encoding:
    def __init__(self, camera: StereoCamera, settings: VideoSettings, clock: Clock) -> None:
        self.camera = camera
        self.settings = settings
        self.clock = clock
        # The frame rate the encoders run at: the configured one while this machine
        # keeps it, 30 when it cannot (frame_rate.py); frames between are passed over.
        self.frame_rate = FrameRateRule(settings.fps, settings.fps_auto)
        self._last: tuple[int, float] | None = None  # the last frame pulled: seq, time
        self._encoded_at = -float("inf")  # the last encoded frame's capture time
        # One encoder per codec and layer in use (H.264 full; VP8 only while a viewer
        # needs it; the low layer only while a viewer takes it), each shared by all of
        # its viewers.
        self.encoders: dict[tuple[str, Layer], PacketEncoder] = {}
        self.broadcasters: dict[tuple[str, Layer], Broadcaster] = {}
        # The operator's own stream (rate_control.py): its rate, size and frame rate
        # follow the operator's link; None while no operator's peer has one.
        self.operator_rate: RateControl | None = None
        self._operator_frames = 0  # frames offered to it (every n-th is encoded)
        self.operator_fec_share = 0.0  # FEC packets per media packet to the operator
        self.encoder = self.encoder_for("H264")
        # H.264 bits/s sent, per layer
        self.layer_rate = {layer: RateMeter() for layer in (*LAYERS, OPERATOR)}
        self._grab = ThreadPoolExecutor(1, thread_name_prefix="video-grab")
        self._encode = ThreadPoolExecutor(1, thread_name_prefix="video-encode")
        self.capture_interarrival = InterArrival("video_capture")
        self.encode_ms = StreamStats("video_encode", "ms")
        self.frame_bytes = StreamStats("video_frame_bytes", "B")
        self.keyframe_bytes = StreamStats("video_keyframe_bytes", "B", capacity=100)
        self.frames_encoded = 0
        self._no_signal_seq = 0
        # Taps on the full layer's H.264, by name: the recording's (backend/recording/
        # video.py) while one runs, the media server's feed (backend/media/relay.py) while
        # someone watches through it. Each gets every packet the viewers get, the same
        # bytes (no second encode); while any is set the pipeline captures and encodes
        # H.264 even with no direct viewer.
        self.taps: dict[str, Callable[[EncodedFrame], None]] = {}

    @property
    def camera_fps(self) -> float:
        """The rate the camera delivers (a real device may grant less than asked)."""
        fps = float(getattr(self.camera, "fps", 0.0) or 0.0)
        return fps if fps > 0 else self.settings.fps

    @property
    def fps(self) -> float:
        """The frame rate encoded now: the rule's, never above the camera's."""
        return min(self.frame_rate.target, self.camera_fps)

    @property
    def fps_why(self) -> str:
        camera = self.camera_fps
        if camera < self.frame_rate.target:
            return f"the camera delivers {camera:g} fps (asked for {self.settings.fps:g})"
        return self.frame_rate.why

    def layer_size(self, layer: Layer) -> tuple[int, int]:
        """One eye's size in ``layer``."""
        if layer == OPERATOR:
            rate = self.operator_rate
            layer = "low" if rate is not None and rate.size == "low" else "full"
        if layer == "full":
            return self.camera.width, self.camera.height
        return low_size(self.camera.width, self.camera.height, self.settings.low_scale)

    def encoder_for(self, codec: str, layer: Layer = "full") -> PacketEncoder:
        """The encoder of ``codec`` in ``layer``, made (with its broadcaster) on first use."""
        key = (codec, layer)
        if key not in self.encoders:
            self.encoders[key] = self._new_encoder(codec, layer)
            # (the encoder of the moment: the operator's is replaced when its size changes)
            self.broadcasters[key] = Broadcaster(
                lambda: self.encoders[key].request_keyframe(), self.clock.now
            )
        return self.encoders[key]

    def _new_encoder(self, codec: str, layer: Layer) -> PacketEncoder:
        s = self.settings
        width, height = self.layer_size(layer)
        enc = ENCODERS[codec](
            2 * width,
            height,
            self.fps,
            min(s.bitrate, s.low_bitrate) if layer == "low" else s.bitrate,
            s.keyframe_interval,
            cbr=s.cbr and layer != OPERATOR,  # (filler would fill the operator's link)
        )
        if layer == OPERATOR and self.operator_rate is not None:
            enc.set_bitrate(self.operator_rate.media_bps(self.operator_fec_share))
        return enc

    def follow_operator_rate(self, fec_share: float) -> None:
        """The operator's rate control changed (or its FEC share did): the encoder's
        bitrate follows from the next frame; a new size takes a new encoder, whose first
        frame is a key frame (the operator's track waits for none: it was on this
        broadcaster already, and a key frame is what a new size needs)."""
        rate = self.operator_rate
        self.operator_fec_share = fec_share
        for (codec, layer), enc in list(self.encoders.items()):
            if layer != OPERATOR or rate is None:
                continue
            if (enc.width // 2, enc.height) != self.layer_size(OPERATOR):
                self.encoders[(codec, layer)] = self._new_encoder(codec, layer)
            else:
                enc.set_bitrate(rate.media_bps(fec_share))

    def start_tap(self, tap: Callable[[EncodedFrame], None], name: str = "recording") -> None:
        """Hand every H.264 packet to ``tap`` from now on, and ask for a keyframe (shared
        and rate-limited like a viewer's) so it can start on one."""
        self.taps[name] = tap
        self.broadcaster.request_keyframe()

    def stop_tap(self, name: str = "recording") -> None:
        self.taps.pop(name, None)

    @property
    def broadcaster(self) -> Broadcaster:
        return self.broadcasters[("H264", "full")]

    @property
    def viewers(self) -> int:
        return sum(b.viewers for b in self.broadcasters.values())

    async def run(self) -> None:
        """Capture and encode while anyone takes the video (the pipeline's task)."""
        loop = asyncio.get_running_loop()
        seq = 0
        while True:
            if self.viewers == 0 and not self.taps:
                # Nobody to send to and nothing recorded: pull no frames, so a camera that
                # renders on demand (the simulated one) does not take ~10 % of a core from
                # the force stream.
                self._last = None  # (the gap until someone watches again is no skip)
                await asyncio.sleep(IDLE_POLL_S)
                continue
            # Recording: every frame, oldest first (a skipped one would be missing from
            # the dataset); only live viewers: the newest.
            every = bool(self.taps)
            frame = await loop.run_in_executor(self._grab, self.camera.next_frame, seq, 0.5, every)
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
                self._last = None
                await self._encode_and_publish(loop, frame)
                continue
            if self._last is None:
                self.frame_rate.start(self.clock.now())
            skipped = self._skipped(frame)
            seq = frame.seq
            self.capture_interarrival.tick(frame.time)
            now = self.clock.now()
            if not self._due(frame):
                self.frame_rate.frame(now, skipped, None)  # passed over at this rate
                continue
            self._encoded_at = frame.time
            work_ms = await self._encode_and_publish(loop, frame)
            self.frame_rate.frame(now, skipped, work_ms)
            if self.frame_rate.decide(now):
                self._follow_frame_rate()

    def _skipped(self, frame: StereoFrame) -> int:
        """Frames the camera made (or should have, on its grid) between the last one
        pulled and ``frame``: a gap in their numbers (the loop was busy) or in their
        times (the camera fell behind)."""
        last, self._last = self._last, (frame.seq, frame.time)
        if last is None or frame.seq <= last[0]:
            return 0
        by_time = round((frame.time - last[1]) * self.camera_fps) - 1
        return max(frame.seq - last[0] - 1, by_time, 0)

    def _due(self, frame: StereoFrame) -> bool:
        """Whether ``frame`` is encoded at the rate of the moment (a camera faster
        than it: every n-th frame, on the rate's grid within half a camera frame)."""
        fps, camera = self.fps, self.camera_fps
        if fps >= camera * 0.99:
            return True
        return frame.time >= self._encoded_at + 1.0 / fps - 0.5 / camera

    def _follow_frame_rate(self) -> None:
        """The rule changed the rate: said once, and every encoder made again for it
        (libx264's rate control spends the bitrate over its configured frame rate: at
        60 fps configured and 30 fed, half of it); each new encoder starts on a key
        frame, which is every viewer's and the recording's new start."""
        down = self.frame_rate.target < self.settings.fps
        log.log(
            logging.WARNING if down else logging.INFO,
            "video: %g fps: %s",
            self.fps,
            self.frame_rate.why,
        )
        for codec, layer in list(self.encoders):
            self.encoders[(codec, layer)] = self._new_encoder(codec, layer)

    async def _encode_and_publish(
        self, loop: asyncio.AbstractEventLoop, frame: StereoFrame
    ) -> float:
        """Encode ``frame`` in every layer someone takes, then hand all of it out at
        once: a viewer moving between layers on this frame's keyframe finds the other
        layer's copy of the same frame still queued (and drops it), never already sent
        (two pictures with one RTP timestamp). Returns the time all of it took on the
        encode thread (ms)."""
        out: list[tuple[tuple[str, Layer], list[EncodedFrame]]] = []
        work = [0.0]

        def timed(fn: Callable[[StereoFrame], Any], source: StereoFrame) -> Any:
            started = time.perf_counter()
            try:
                return fn(source)
            finally:
                work[0] += (time.perf_counter() - started) * 1000

        small: StereoFrame | None = None
        for key, broadcaster in list(self.broadcasters.items()):
            layer = key[1]
            tapped = bool(self.taps) and key == ("H264", "full")
            if broadcaster.sending == 0 and not tapped:
                continue  # nobody on this layer, nothing recorded: no encoding
            if layer == OPERATOR and self._operator_skips():
                continue  # its rate carries only every n-th frame
            shrunk = self.layer_size(layer) != self.layer_size("full")
            if shrunk and small is None:
                small = await loop.run_in_executor(self._encode, timed, self._shrink, frame)
            source = small if shrunk and small is not None else frame
            encode = self.encoders[key].encode
            out.append((key, await loop.run_in_executor(self._encode, timed, encode, source)))
        now = self.clock.now()
        for key, encoded_frames in out:
            for encoded in encoded_frames:
                if key[0] == "H264":
                    self.layer_rate[key[1]].add(encoded.size * 8, now)
                if key == ("H264", "full"):
                    self._record(encoded)
                    for tap in list(self.taps.values()):
                        tap(encoded)  # must not block: a bounded hand-over
                self.broadcasters[key].publish(encoded)
        return work[0]

    def _operator_skips(self) -> bool:
        """Whether the operator's stream leaves this frame out (half its frame rate
        when its link carries too little for the full rate: rate_control.py)."""
        self._operator_frames += 1
        every = 1 if self.operator_rate is None else self.operator_rate.every
        return self._operator_frames % every != 0

    def _shrink(self, frame: StereoFrame) -> StereoFrame:
        width, height = self.layer_size("low")
        small = cv2.resize(frame.sbs, (2 * width, height), interpolation=cv2.INTER_AREA)
        return StereoFrame(frame.seq, frame.time, small, frame.skew)

    def _record(self, e: EncodedFrame) -> None:
        self.frames_encoded += 1
        self.encode_ms.record(e.encode_ms)
        self.frame_bytes.record(e.size)
        if e.keyframe:
            self.keyframe_bytes.record(e.size)

    async def close(self) -> None:
        """The camera stopped (on its own thread), the threads ended."""
        await asyncio.get_running_loop().run_in_executor(self._grab, self.camera.stop)
        self._grab.shutdown(wait=False)
        self._encode.shutdown(wait=False)

    def stats(self, now: float) -> dict[str, Any]:
        """The camera's, the encoders' and the layers' figures (``VideoPipeline.stats``)."""
        cap = self.capture_interarrival.summary()
        enc = self.encode_ms.summary()
        size = self.frame_bytes.summary()
        keys = self.keyframe_bytes.values()
        return {
            "camera": {
                "name": self.camera.name,
                "status": self.camera.status.value,
                "message": self.camera.status_message,
            },
            "capture_fps": 1000.0 / cap.mean if cap.count and cap.mean > 0 else None,
            # The frame rate encoded now, the configured one, and why they differ (the
            # rule in frame_rate.py, or a camera that delivers less).
            "fps_target": self.fps,
            "fps_configured": self.settings.fps,
            "fps_why": self.fps_why,
            "fps_rule": self.frame_rate.as_dict(),
            "encode_ms_p50": enc.p50 if enc.count else None,
            "encode_ms_p99": enc.p99 if enc.count else None,
            "bytes_per_frame_mean": size.mean if size.count else None,
            "keyframe_bytes_last": keys[-10:].tolist(),
            "frames_encoded": self.frames_encoded,
            "codecs": {
                codec: sum(b.viewers for (c, _), b in self.broadcasters.items() if c == codec)
                for codec, _ in self.broadcasters
            },
            "layers": {
                layer: {
                    "width": self.layer_size(layer)[0],
                    "height": self.layer_size(layer)[1],
                    "viewers": sum(
                        b.viewers for (_, x), b in self.broadcasters.items() if x == layer
                    ),
                    "kbps": None
                    if (bps := self.layer_rate[layer].bps(now)) is None
                    else bps / 1000,
                }
                for layer in (*LAYERS, OPERATOR)
                if layer != OPERATOR or ("H264", OPERATOR) in self.broadcasters
            },
            "keyframes_forced": sum(b.keyframes.forced for b in self.broadcasters.values()),
        }

    @property
    def camera_running(self) -> bool:
        return self.camera.status is CameraStatus.RUNNING
