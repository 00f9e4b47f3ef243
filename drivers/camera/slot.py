"""The thesis's double buffer (§3.2.2): the capture thread writes the newest frame,
readers take the newest one they have not seen. Capture never waits for a reader
and a reader never gets a stale frame twice."""

from __future__ import annotations

import threading

from telerobot.drivers.base import StereoFrame


class FrameSlot:
    def __init__(self) -> None:
        self._frame: StereoFrame | None = None
        self._cond = threading.Condition()
        self.dropped = 0  # frames replaced before anyone read them

    def put(self, frame: StereoFrame) -> None:
        with self._cond:
            if self._frame is not None and not self._read:
                self.dropped += 1
            self._frame, self._read = frame, False
            self._cond.notify_all()

    def next_frame(self, after_seq: int, timeout: float) -> StereoFrame | None:
        with self._cond:
            ok = self._cond.wait_for(
                lambda: self._frame is not None and self._frame.seq > after_seq, timeout
            )
            if not ok:
                return None
            self._read = True
            return self._frame

    _read = True
