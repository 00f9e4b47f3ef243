"""The video's frame rate: the configured one (``video_fps``, e.g. 60) while the media
worker keeps it with room to spare, 30 when it cannot (docs/video.md, "Frame rate").

Each captured frame the encode loop pulls is counted here: the frames it skipped before
it (the camera made them and the loop was still busy, or they came late: a gap in the
frames' numbers or times), and, for a frame it encoded, the time all of its encodes
took (every layer and codec someone takes, the low layer's shrink included: wall time
on the encode thread, so a machine whose cores are busy shows it). The rule, judged
once a second over the last ``WINDOW_S``:

* **down** to ``FLOOR_FPS`` when the window's 90th percentile of a frame's encoding is
  above ``DROP_WORK_SHARE`` of the configured frame period (85 %: 14.2 ms at 60 fps:
  one frame in ten leaves the encode thread almost no pause before the next, which
  with the camera's rendering and the packets beside it is a whole core of a 2-core
  machine whose other core is the forces'; bench.force_under_video measured the forces
  unharmed at 2×1280×720, 60 fps, p90 10–13 ms), or more than ``DROP_SKIPPED_SHARE``
  of the camera's frames were skipped (the encoder does not keep up at all);
* **back up** only after ``up_hold_s`` (``UP_HOLD_S``, 30 s) in which every judgement
  was clean: that 90th percentile at most ``UP_WORK_SHARE`` of the configured period
  (60 %: 10 ms at 60 fps; a frame's work is about the same at either rate) and at most
  ``UP_SKIPPED_SHARE`` skipped. A drop within ``FAILED_PROBE_S`` of going up doubles
  the next wait (up to ``MAX_UP_HOLD_S``), so a machine on the edge tries less and
  less often; a long stretch at the configured rate starts the wait afresh.

A window is judged only when it holds ``WINDOW_S`` of frames since the last change
(the figures of one rate say little of the other), so two changes are never closer
than ``WINDOW_S``, and going up never sooner than ``up_hold_s`` after going down.
With nobody watching no frame is encoded and nothing is judged: the rate stays as it
was. Pure: time is passed in (the pipeline's injected clock); ``Encoding`` follows
``target``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

FLOOR_FPS = 30.0  # never below this (nor above the configured rate)
WINDOW_S = 5.0  # the figures judged: the frames of the last this many seconds
JUDGE_S = 1.0  # judged this often
QUANTILE = 90.0  # the percentile of a frame's encoding judged
DROP_WORK_SHARE = 0.85  # of the configured frame period: down above it
UP_WORK_SHARE = 0.6  # …and back up only at or below this
DROP_SKIPPED_SHARE = 0.05  # of the camera's frames skipped: down above it
UP_SKIPPED_SHARE = 0.01  # …back up only at or below this
MIN_ENCODED = 10  # frames encoded in a window, at least, for it to be judged
UP_HOLD_S = 30.0  # clean this long at the floor: back to the configured rate
MAX_UP_HOLD_S = 240.0
FAILED_PROBE_S = 60.0  # down again within this of going up: the next wait doubles
RESET_HOLD_S = 300.0  # at the configured rate this long: the wait starts afresh
# The first seconds after encoding starts (a first viewer, or one after nobody watched)
# are not judged: the first key frame, the peer's handshake on the worker's loop and a
# camera waking up skipped 14 % of the frames at 2×1280×720 on a machine that then
# kept 60 with room (0 skipped, p90 7 ms).
START_S = 3.0


@dataclass
class FrameRateRule:
    """The frame rate the encoders run at (``target``) and why; ``configured``: the
    server's ``video_fps``."""

    configured: float
    auto: bool = True  # False: the configured rate whatever happens (video_fps_auto)
    target: float = 0.0
    why: str = "configured"
    changes: int = 0
    changed_at: float = -math.inf
    clean_since: float | None = None  # at the floor: every judgement clean since then
    up_hold_s: float = UP_HOLD_S
    judged_at: float = -math.inf
    started_at: float = -math.inf  # encoding (re)started: nothing counted until START_S
    work_p90_ms: float | None = None  # the last judgement's figures
    skipped_share: float | None = None
    _work: deque[tuple[float, float]] = field(default_factory=deque)  # (t, ms)
    _pulled: deque[tuple[float, int]] = field(default_factory=deque)  # (t, skipped)

    def __post_init__(self) -> None:
        self.target = self.configured
        self.why = f"configured ({self.configured:g} fps)"
        if not self.auto:
            self.why += ", kept whatever the machine does (TELEROBOT_VIDEO_FPS_AUTO=false)"

    @property
    def floor(self) -> float:
        return min(FLOOR_FPS, self.configured)

    @property
    def active(self) -> bool:
        """Whether there is anything to drop to (a rate of 30 or less is kept as is)."""
        return self.auto and self.configured > self.floor

    @property
    def period_ms(self) -> float:
        """The configured rate's frame period: what a frame's encoding is judged by."""
        return 1000.0 / self.configured

    def start(self, now: float) -> None:
        """Encoding starts again (someone watches after nobody did): the window starts
        afresh ``START_S`` from now."""
        self.started_at = now
        self._work.clear()
        self._pulled.clear()

    def frame(self, now: float, skipped: int, work_ms: float | None) -> None:
        """A frame pulled at ``now``, ``skipped`` frames after the one before it;
        ``work_ms``: all of its encoding (None: passed over, not encoded at this rate)."""
        if now - self.started_at < START_S:
            return
        self._pulled.append((now, max(0, skipped)))
        if work_ms is not None:
            self._work.append((now, work_ms))

    def decide(self, now: float) -> bool:
        """Judge the window (at most every ``JUDGE_S``); True if ``target`` changed."""
        if not self.active or now - self.judged_at < JUDGE_S:
            return False
        self.judged_at = now
        for queue in (self._work, self._pulled):
            while queue and queue[0][0] <= now - WINDOW_S:
                queue.popleft()
        if now - max(self.changed_at, self.started_at + START_S) < WINDOW_S:
            return False  # not a whole window of this rate yet
        if len(self._work) < MIN_ENCODED:
            if self.target < self.configured:
                self.clean_since = None  # nobody watching: no evidence of room
            return False
        work = float(np.percentile([ms for _, ms in self._work], QUANTILE))
        skipped = sum(n for _, n in self._pulled)
        share = skipped / (skipped + len(self._pulled))
        self.work_p90_ms, self.skipped_share = work, share
        if self.target > self.floor:
            if now - self.changed_at > RESET_HOLD_S:
                self.up_hold_s = UP_HOLD_S
            trouble = self._trouble(work, share)
            if not trouble:
                return False
            if now - self.changed_at < FAILED_PROBE_S and self.changes > 0:
                self.up_hold_s = min(MAX_UP_HOLD_S, 2 * self.up_hold_s)
            self._change(self.floor, f"{trouble}: {self.floor:g} fps", now)
            self.clean_since = now
            return True
        clean = work <= UP_WORK_SHARE * self.period_ms and share <= UP_SKIPPED_SHARE
        if not clean or self.clean_since is None:
            self.clean_since = now
            return False
        if now - self.clean_since < self.up_hold_s:
            return False
        self._change(
            self.configured,
            f"clean for {now - self.clean_since:.0f} s (encoding {work:.1f} ms a frame,"
            f" p{QUANTILE:.0f}; {share:.1%} skipped): {self.configured:g} fps again",
            now,
        )
        return True

    def _trouble(self, work: float, share: float) -> str:
        """Why the configured rate is too much ('' if it is not)."""
        limit = DROP_WORK_SHARE * self.period_ms
        if work > limit:
            return (
                f"encoding took {work:.1f} ms a frame (p{QUANTILE:.0f} over {WINDOW_S:g} s),"
                f" over {limit:.1f} ms ({DROP_WORK_SHARE:.0%} of {self.configured:g} fps's"
                f" {self.period_ms:.1f} ms)"
            )
        if share > DROP_SKIPPED_SHARE:
            return (
                f"{share:.0%} of the camera's frames skipped over {WINDOW_S:g} s"
                f" (over {DROP_SKIPPED_SHARE:.0%})"
            )
        return ""

    def _change(self, target: float, why: str, now: float) -> None:
        self.target, self.why = target, why
        self.changed_at = now
        self.changes += 1
        self._work.clear()
        self._pulled.clear()

    def as_dict(self) -> dict[str, Any]:
        """The rule's figures for the video's stats."""
        return {
            "work_ms_p90": self.work_p90_ms,
            "skipped_share": self.skipped_share,
            "window_s": WINDOW_S,
            "down_above_ms": DROP_WORK_SHARE * self.period_ms if self.active else None,
            "up_below_ms": UP_WORK_SHARE * self.period_ms if self.active else None,
            "up_hold_s": self.up_hold_s,
            "changes": self.changes,
        }
