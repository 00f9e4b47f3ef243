"""Real stereo cameras through OpenCV: two devices, or one side-by-side device.

Two devices are grabbed back to back and only then retrieved (decoded), which keeps
the exposure skew to the time between two grabs; the skew is reported with every
frame. A device that fails or disappears puts the camera in FAILED with the reason;
the capture thread keeps retrying and resumes on its own.

The frame rate is asked of each device (``CAP_PROP_FPS``); a device that grants less
(most UVC cameras offer 60 fps only at smaller sizes or in MJPEG) is taken at its own
rate: ``fps`` becomes what it grants, the status says so, and the pipeline encodes at
that rate (``fps_target``, ``fps_why`` in the video's stats). A device that does not
say (0) is taken as asked.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Self

import cv2
import numpy as np

from telerobot.drivers.base import CameraStatus, DeviceContext, StereoFrame, TelerobotError
from telerobot.drivers.camera.opencv_settings import OpenCVSettings
from telerobot.drivers.camera.slot import FrameSlot
from telerobot.drivers.threads import WorkerThread

log = logging.getLogger(__name__)

Device = int | str  # a device index, a /dev/video path, or a video file/URL


@dataclass(frozen=True)
class OpenCVConfig:
    """What the OpenCV cameras read from the settings."""

    devices: tuple[Device, ...] = (0, 1)  # stereo: left, right; side by side: the first
    width: int = 1280  # of one eye
    height: int = 720
    fps: float = 30.0

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        return cls(
            devices=tuple(
                int(d) if d.isdigit() else d for d in OpenCVSettings.of(settings).camera_devices
            ),
            width=int(settings["video_width"]),
            height=int(settings["video_height"]),
            fps=float(settings["video_fps"]),
        )


class _OpenCVCapture:
    name = "opencv"

    def __init__(
        self,
        *,
        width: int,
        height: int,
        fps: float,
        retry_s: float = 2.0,
        time_source: Callable[[], float] = time.monotonic,
    ) -> None:
        self.width, self.height, self.fps = width, height, fps
        self.asked_fps = fps  # what the settings asked of the devices
        self.retry_s = retry_s
        self._now = time_source
        self._slot = FrameSlot()
        self._seq = 0
        self._worker = WorkerThread(self._run, f"{self.name}-capture")
        self._stop = self._worker.stopping
        self._status = CameraStatus.STOPPED
        self._message = "stopped"
        self.retries = 0
        self.last_skew = 0.0

    @classmethod
    def default_rig(cls, settings: Mapping[str, Any]) -> str:
        """The driver and its devices: each rig of real cameras keeps its calibration."""
        devices = "-".join(
            str(d).strip("/").replace("/", "_") for d in OpenCVSettings.of(settings).camera_devices
        )
        return f"{settings['camera']}-{devices}"[:64]

    @property
    def status(self) -> CameraStatus:
        return self._status

    @property
    def status_message(self) -> str:
        return self._message

    def show_board(self, view: int | None) -> None:
        raise TelerobotError(
            "only the simulated camera can show a board: hold a printed ChArUco "
            "board in front of the real cameras instead"
        )

    def _fail(self, message: str) -> None:
        if self._status is not CameraStatus.FAILED or self._message != message:
            log.warning("%s: %s", self.name, message)
        self._status, self._message = CameraStatus.FAILED, message

    # subclasses -----------------------------------------------------------
    def _open(self) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _read(self) -> tuple[np.ndarray, float, float] | None:
        """One side-by-side RGB frame, its capture time and the skew; None on failure."""
        raise NotImplementedError

    def _granted(self, caps: list[cv2.VideoCapture]) -> None:
        """Take the rate the devices grant (the slowest's), if they say one below the
        rate asked for."""
        said = [f for f in (float(c.get(cv2.CAP_PROP_FPS) or 0.0) for c in caps) if f > 0]
        granted = min(said, default=self.asked_fps)
        self.fps = min(self.asked_fps, granted)
        if self.fps < self.asked_fps:
            log.warning(
                "%s: asked for %g fps, the device gives %g: capturing at that",
                self.name,
                self.asked_fps,
                self.fps,
            )

    # thread ---------------------------------------------------------------
    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop(timeout=5)
        self._status, self._message = CameraStatus.STOPPED, "stopped"

    def next_frame(self, after_seq: int, timeout: float, every: bool = False) -> StereoFrame | None:
        return self._slot.next_frame(after_seq, timeout, every)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self._open()
            except OSError as exc:
                self._fail(str(exc))
                self.retries += 1
                self._stop.wait(self.retry_s)
                continue
            period = 1.0 / self.fps  # (the rate the device granted)
            less = f" (asked for {self.asked_fps:g})" if self.fps < self.asked_fps else ""
            self._status, self._message = CameraStatus.RUNNING, f"capturing {self.fps:g} fps{less}"
            next_t = self._now()
            while not self._stop.is_set():
                got = self._read()
                if got is None:
                    self._fail("the camera stopped delivering frames; retrying")
                    break
                sbs, t, skew = got
                self._seq += 1
                self.last_skew = skew
                self._slot.put(StereoFrame(self._seq, t, sbs, skew))
                next_t += period
                delay = next_t - self._now()
                if delay > 0:
                    self._stop.wait(delay)  # real devices block in read; files are paced here
                else:
                    next_t = self._now()
            self._close()
            if not self._stop.is_set():
                self.retries += 1
                self._stop.wait(self.retry_s)


def _to_rgb(bgr: np.ndarray, width: int, height: int) -> np.ndarray:
    if bgr.shape[1] != width or bgr.shape[0] != height:
        bgr = cv2.resize(bgr, (width, height), interpolation=cv2.INTER_AREA)
    result: np.ndarray = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return result


def _open_capture(device: Device, width: int, height: int, fps: float) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(device)
    if not cap.isOpened():
        cap.release()
        raise OSError(f"cannot open camera {device!r}: not found or busy")
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
    cap.set(cv2.CAP_PROP_FPS, fps)
    cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)  # newest frame, not a queue of old ones
    return cap


class OpenCVStereoCamera(_OpenCVCapture):
    """Two cameras, left and right."""

    name = "opencv-stereo"

    def __init__(
        self,
        left: Device,
        right: Device,
        *,
        width: int = 1280,
        height: int = 720,
        fps: float = 30.0,
        **kw: object,
    ) -> None:
        super().__init__(width=width, height=height, fps=fps, **kw)  # type: ignore[arg-type]
        self.devices = (left, right)
        self._caps: list[cv2.VideoCapture] = []

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        c = OpenCVConfig.from_settings(settings)
        return cls(c.devices[0], c.devices[1], width=c.width, height=c.height, fps=c.fps)

    def _open(self) -> None:
        self._close()
        self._caps = [
            _open_capture(d, self.width, self.height, self.asked_fps) for d in self.devices
        ]
        self._granted(self._caps)

    def _close(self) -> None:
        for cap in self._caps:
            cap.release()
        self._caps = []

    def _read(self) -> tuple[np.ndarray, float, float] | None:
        left, right = self._caps
        t0 = self._now()
        if not left.grab():
            return None
        t1 = self._now()
        if not right.grab():
            return None
        ok_l, img_l = left.retrieve()
        ok_r, img_r = right.retrieve()
        if not (ok_l and ok_r):
            return None
        sbs = np.concatenate(
            [_to_rgb(img_l, self.width, self.height), _to_rgb(img_r, self.width, self.height)],
            axis=1,
        )
        return sbs, (t0 + t1) / 2, t1 - t0


class OpenCVSideBySideCamera(_OpenCVCapture):
    """One device that delivers both eyes side by side (e.g. a USB stereo camera)."""

    name = "opencv-sbs"

    def __init__(
        self,
        device: Device,
        *,
        width: int = 1280,
        height: int = 720,
        fps: float = 30.0,
        **kw: object,
    ) -> None:
        super().__init__(width=width, height=height, fps=fps, **kw)  # type: ignore[arg-type]
        self.device = device
        self._cap: cv2.VideoCapture | None = None

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        c = OpenCVConfig.from_settings(settings)
        return cls(c.devices[0], width=c.width, height=c.height, fps=c.fps)

    def _open(self) -> None:
        self._close()
        self._cap = _open_capture(self.device, 2 * self.width, self.height, self.asked_fps)
        self._granted([self._cap])

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _read(self) -> tuple[np.ndarray, float, float] | None:
        assert self._cap is not None
        ok, img = self._cap.read()
        t = self._now()
        if not ok:
            return None
        return _to_rgb(img, 2 * self.width, self.height), t, 0.0
