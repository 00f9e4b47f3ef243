"""The server's stereo video as two cameras, ``left`` and ``right``, for the LeRobot robot
plugin: a WebRTC peer (aiortc, as ``harness.aiortc_viewers.open_viewer``) in a thread of its own
that keeps the newest decoded frame, split into its two eyes, with the time it was
captured on the server's clock.

The capture time comes from the frame itself: the simulated cameras draw it as a
timecode in the left image's corner (``telerobot.drivers.camera.timecode``), in the
server's clock, the clock of the arm's STATEs; so a frame is matched to the state
sampled when it was captured with no clock error at all. A real camera draws none: its
frames are then dated by their arrival, moved to the server's clock (``capture_source``
says "arrival", and the skew the plugin reports then includes the video's latency).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import SecretStr

from telerobot.client.lerobot.parts import detail
from telerobot.client.tokens import bearer
from telerobot.drivers.camera import timecode

log = logging.getLogger(__name__)

Image = npt.NDArray[np.uint8]
CAMERAS = ("left", "right")
MAX_AGE_S = 2.0  # a frame older than this on arrival: its "timecode" is only pixels


@dataclass(frozen=True)
class StereoFrame:
    seq: int  # frames received before this one
    capture_time: float  # server clock (s)
    left: Image
    right: Image
    capture_source: str  # "timecode" or "arrival"


def capture_time(code: int | None, server_now: float) -> float | None:
    """The server-clock time a timecode ``code`` stands for, the newest such time at or
    before ``server_now`` (the code wraps every ~7 minutes); None if that is more than
    ``MAX_AGE_S`` ago: no timecode, only a picture (a real camera's corner)."""
    if code is None:
        return None
    age = timecode.elapsed(code, server_now)
    return server_now - age if age <= MAX_AGE_S else None


class StereoReceiver:
    def __init__(
        self,
        url: str,
        token: SecretStr,
        size: tuple[int, int],
        server_clock: Callable[[], float],
        *,
        timeout_s: float = 30.0,
    ) -> None:
        self.url = url if url.endswith("/") else url + "/"
        self.token = token
        self.width, self.height = size
        self.server_clock = server_clock
        self.timeout_s = timeout_s
        self._latest: StereoFrame | None = None
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stopped: asyncio.Event | None = None
        self.error: str | None = None
        self.received = 0
        self.decoded_size: tuple[int, int] | None = None  # one eye as it arrives (w, h)
        self.server_height = 0  # of one eye as the server's cameras capture it
        self.server_fps = 0.0  # the rate the server's cameras capture at (0: not said)

    # ------------------------------------------------------------ running
    def start(self) -> None:
        """Connect; returns once the first frame is in (or raises why not)."""
        self._thread = threading.Thread(target=self._run, name="lerobot-cameras", daemon=True)
        self._thread.start()
        with self._cond:
            self._cond.wait_for(lambda: self._latest is not None or self.error, self.timeout_s)
        if self._latest is None:
            self.stop()
            raise ConnectionError(
                f"no video from {self.url} within {self.timeout_s:g} s"
                + (f": {self.error}" if self.error else "")
            )

    def stop(self) -> None:
        loop, stopped = self._loop, self._stopped
        if loop is not None and stopped is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):
                loop.call_soon_threadsafe(stopped.set)
        if self._thread is not None:
            self._thread.join(10)
            self._thread = None

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except Exception as exc:  # said to whoever waits, and in the log
            self.error = f"{type(exc).__name__}: {exc}"
            log.error("cameras: %s", self.error)
        with self._cond:
            self._cond.notify_all()

    async def _main(self) -> None:
        import httpx
        from aiortc import RTCPeerConnection, RTCSessionDescription

        self._loop = asyncio.get_running_loop()
        self._stopped = asyncio.Event()
        pc = RTCPeerConnection()
        try:
            pc.addTransceiver("video", direction="recvonly")
            tracks: asyncio.Queue[Any] = asyncio.Queue()
            pc.on("track", tracks.put_nowait)
            await pc.setLocalDescription(await pc.createOffer())
            headers = bearer(self.token)
            async with httpx.AsyncClient(base_url=self.url, timeout=self.timeout_s) as http:
                with contextlib.suppress(httpx.HTTPError, ValueError, KeyError):
                    video = (await http.get("api/v1/video")).json()
                    self.server_height = int(video["height"])
                    self.server_fps = float(video["fps"])
                offer = {"sdp": pc.localDescription.sdp, "type": "offer"}
                r = await http.post("api/v1/webrtc/offer", json=offer, headers=headers)
                if r.status_code != 200:
                    raise ConnectionError(
                        f"the server refused the video ({r.status_code}): {detail(r)}"
                    )
                answer = r.json()
                await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
            track = await asyncio.wait_for(tracks.get(), self.timeout_s)
            stopped = asyncio.ensure_future(self._stopped.wait())
            while not self._stopped.is_set():
                got = asyncio.ensure_future(track.recv())
                done, _ = await asyncio.wait({got, stopped}, return_when=asyncio.FIRST_COMPLETED)
                if got not in done:
                    got.cancel()
                    break
                self._take(got.result())
        finally:
            await pc.close()

    def _take(self, frame: Any) -> None:
        arrived = self.server_clock()
        sbs = frame.to_ndarray(format="rgb24")
        eye_w = sbs.shape[1] // 2
        self.decoded_size = (eye_w, sbs.shape[0])
        # The timecode is drawn into the full-size picture; a smaller layer is read scaled.
        left = sbs[:, :eye_w]
        captured = capture_time(self._timecode(left), arrived)
        if (eye_w, sbs.shape[0]) != (self.width, self.height):
            # Scaled by the decoder's own scaler (FFmpeg's swscale): no OpenCV needed.
            sbs = frame.reformat(width=2 * self.width, height=self.height, format="rgb24")
            sbs = sbs.to_ndarray()
        left, right = sbs[:, : self.width], sbs[:, self.width : 2 * self.width]
        with self._cond:
            self._latest = StereoFrame(
                seq=self.received,
                capture_time=arrived if captured is None else captured,
                left=np.ascontiguousarray(left),
                right=np.ascontiguousarray(right),
                capture_source="arrival" if captured is None else "timecode",
            )
            self.received += 1
            self._cond.notify_all()

    def _timecode(self, left: Image) -> int | None:
        """The left image's timecode, drawn at the server's full size (a smaller layer
        is read scaled, which needs OpenCV: without it, None)."""
        if not left.size:
            return None
        scale = left.shape[0] / self.server_height if self.server_height else 1.0
        try:
            return timecode.read(left, scale=scale)
        except ImportError:
            return None

    # ------------------------------------------------------------ reading
    def latest(self) -> StereoFrame | None:
        return self._latest

    def newer_than(self, seq: int, timeout_s: float) -> StereoFrame | None:
        """The newest frame after frame ``seq``, waiting up to ``timeout_s`` for one;
        else the newest there is (a repeat)."""
        with self._cond:
            self._cond.wait_for(
                lambda: self._latest is not None and self._latest.seq > seq, timeout_s
            )
            return self._latest

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()


def wait_s(fps: float) -> float:
    """How long ``get_observation`` waits for the first frame: one and a half frames."""
    return 1.5 / fps if fps > 0 else 0.05
