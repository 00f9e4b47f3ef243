"""The thesis's double buffer (§3.2.2): the capture thread writes the newest frame,
readers take the newest one they have not seen. Capture never waits for a reader
and a reader never gets a stale frame twice.

It keeps the last ``KEEP`` frames, not one: a reader that must see every frame (the
pipeline while a recording is tapped: a frame skipped there is a frame missing from the
dataset) asks with ``every=True`` and gets the oldest it has not seen, so a capture
thread that caught up on its exposure grid after a stall (two frames in quick
succession) loses nothing as long as the reader is at most ``KEEP - 1`` frames behind."""

from __future__ import annotations

import threading
from collections import deque

from telerobot.drivers.base import StereoFrame

KEEP = 8  # frames kept for an every-frame reader: 267 ms at 30 fps (44 MB at 2×1280×720)


class FrameSlot:
    def __init__(self) -> None:
        self._frames: deque[StereoFrame] = deque(maxlen=KEEP)
        self._cond = threading.Condition()
        self._read_seq = 0  # the newest frame handed out
        self.dropped = 0  # frames gone (replaced or pushed out) before anyone read them

    def put(self, frame: StereoFrame) -> None:
        with self._cond:
            if len(self._frames) == KEEP and self._frames[0].seq > self._read_seq:
                self.dropped += 1  # the oldest goes unread
            self._frames.append(frame)
            self._cond.notify_all()

    def next_frame(self, after_seq: int, timeout: float, every: bool = False) -> StereoFrame | None:
        """The newest frame newer than ``after_seq`` (``every``: the oldest kept one),
        waiting up to ``timeout`` s; None if none came."""
        with self._cond:
            ok = self._cond.wait_for(
                lambda: bool(self._frames) and self._frames[-1].seq > after_seq, timeout
            )
            if not ok:
                return None
            if every:
                frame = next(f for f in self._frames if f.seq > after_seq)
            else:
                frame = self._frames[-1]
                # Frames passed over for a newer one are never read: dropped now.
                self.dropped += sum(1 for f in self._frames if self._read_seq < f.seq < frame.seq)
            self._read_seq = max(self._read_seq, frame.seq)
            return frame
