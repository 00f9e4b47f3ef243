"""Two layers of the one stereo stream, and which one each viewer gets.

The full layer is the camera's size at the configured bitrate; the low layer is the
same frames scaled down (half each way by default) at ≤ 1.2 Mbit/s, encoded only while
some viewer takes it. Each is encoded once and shared by everyone on it.

A viewer moves between them by what its own receiver reports over RTCP (``ViewerLink``):
down at once when the link cannot carry the full layer (its bandwidth estimate below
the full layer's rate, a report losing ≥ 5 %, or the round trip grown by a queue); up
again only after the link has stayed clean for a while. Going up is a probe (a
receiver's estimate on the low layer cannot say whether the full one would fit), so a
probe that has to come down again soon doubles the wait before the next one. The
decision is pure: the pipeline calls ``LayerChoice.decide`` about once a second with its
clock's time.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Literal, Protocol

# "operator": the operator's own stream, not shared (rate_control.py); the other two
# are the shared layers every watcher moves between.
Layer = Literal["full", "low", "operator"]
LAYERS: tuple[Layer, ...] = ("full", "low")
OPERATOR: Layer = "operator"
LayerMode = Literal["auto", "full", "low"]  # "auto": chosen by the viewer's link

LOW_SCALE = 0.5  # of each side: 2×1280×720 → 2×640×360
LOW_BITRATE = 1_200_000

DOWN_LOSS = 0.05  # a receiver report losing this share: down at once
UP_LOSS = 0.02  # reports losing less than this count as clean
ESTIMATE_MARGIN = 0.75  # down when the estimate is below this share of the full rate…
# …and has fallen this far from its peak: a congested estimator cuts its estimate
# (GCC: ×0.85), while Chromium's starts near 70 kbit/s and only climbs (~8 %/s) on a
# link with room; a low estimate that is still rising says nothing.
ESTIMATE_FALL = 0.85
QUEUE_RTT_S = 0.25  # down when the round trip exceeds its minimum by this (a queue)
UP_HOLD_S = 8.0  # clean this long on the low layer: try the full one
MAX_UP_HOLD_S = 64.0
FAILED_PROBE_S = 10.0  # back down within this after going up: the probe failed
# A receiver's estimate grows with what it receives (up to ~1.5× that): for this long
# after going up, an estimate still sized by the low layer is no reason to go down.
ESTIMATE_GRACE_S = 10.0
# Trouble in this many receiver reports in a row (about one a second) before going
# down: one report can be a busy machine's hiccup (a late RTCP packet reads as a queue).
CONFIRM_REPORTS = 2


def low_size(width: int, height: int, scale: float = LOW_SCALE) -> tuple[int, int]:
    """One eye's size in the low layer (even numbers, as H.264's 4:2:0 needs)."""
    return max(2, round(width * scale / 2) * 2), max(2, round(height * scale / 2) * 2)


class LinkReport(Protocol):
    estimated_bps: int | None
    fraction_lost: float | None
    rtt_s: float | None
    reports: int


@dataclass
class LayerChoice:
    """One viewer's layer and the memory its hysteresis needs."""

    layer: Layer = "full"
    switches: int = 0
    switched_at: float = -float("inf")
    clean_since: float | None = None  # on the low layer: clean reports since then
    up_hold_s: float = UP_HOLD_S
    min_rtt_s: float | None = None
    peak_bps: int = 0  # the highest estimate on this layer
    seen_reports: int = 0
    strikes: int = 0  # fresh reports in a row that found trouble on the full layer
    why: str = "start"

    def decide(self, link: LinkReport, full_bps: float | None, now: float) -> Layer:
        """The layer from now on, given the viewer's latest reports and the full
        layer's measured rate (bits/s; None: not measured yet)."""
        fresh = link.reports > self.seen_reports
        self.seen_reports = link.reports
        if link.estimated_bps is not None:
            self.peak_bps = max(self.peak_bps, link.estimated_bps)
        if link.rtt_s is not None and link.rtt_s > 0:
            self.min_rtt_s = (
                link.rtt_s if self.min_rtt_s is None else min(self.min_rtt_s, link.rtt_s)
            )
        if self.layer == "full":
            trusted = now - self.switched_at >= ESTIMATE_GRACE_S
            trouble = self._trouble(link, full_bps if trusted else None, fresh)
            if fresh:
                self.strikes = self.strikes + 1 if trouble else 0
            if trouble and self.strikes >= CONFIRM_REPORTS:
                if now - self.switched_at < FAILED_PROBE_S:
                    self.up_hold_s = min(MAX_UP_HOLD_S, self.up_hold_s * 2)
                self._switch("low", trouble, now)
                self.clean_since = now
            elif now - self.switched_at > 3 * FAILED_PROBE_S:
                self.up_hold_s = UP_HOLD_S  # long on full: the next drop starts afresh
            return self.layer
        # On the low layer the estimate says nothing about the full one: loss and queue only.
        trouble = self._trouble(link, None, fresh)
        if trouble or (fresh and (link.fraction_lost or 0.0) >= UP_LOSS):
            self.clean_since = now
        elif self.clean_since is not None and now - self.clean_since >= self.up_hold_s:
            self._switch("full", f"clean for {now - self.clean_since:.0f} s: trying it", now)
        return self.layer

    def _trouble(self, link: LinkReport, full_bps: float | None, fresh: bool) -> str:
        """Why the full layer does not fit this link now ('' if it may)."""
        if fresh and link.fraction_lost is not None and link.fraction_lost >= DOWN_LOSS:
            return f"{link.fraction_lost:.0%} lost"
        if (
            link.estimated_bps is not None
            and full_bps is not None
            and link.estimated_bps < ESTIMATE_MARGIN * full_bps
            and link.estimated_bps < ESTIMATE_FALL * self.peak_bps
        ):
            return (
                f"estimate {link.estimated_bps / 1e6:.2f} Mbit/s below the full layer's"
                f" {full_bps / 1e6:.2f}"
            )
        if (
            link.rtt_s is not None
            and self.min_rtt_s is not None
            and link.rtt_s > self.min_rtt_s + QUEUE_RTT_S
        ):
            rtt, least = link.rtt_s * 1000, self.min_rtt_s * 1000
            return f"round trip {rtt:.0f} ms (a queue: it was {least:.0f})"
        return ""

    def _switch(self, layer: Layer, why: str, now: float) -> None:
        self.layer, self.why = layer, why
        self.switched_at = now
        self.peak_bps = 0
        self.strikes = 0
        self.switches += 1


class RateMeter:
    """Bits per second over the last ``window_s`` (a layer's measured rate: what the
    encoder really makes of the scene, often far below its cap)."""

    def __init__(self, window_s: float = 2.0, capacity: int = 512) -> None:
        self.window_s = window_s
        self._samples: deque[tuple[float, int]] = deque(maxlen=capacity)

    def add(self, bits: int, now: float) -> None:
        self._samples.append((now, bits))

    def bps(self, now: float) -> float | None:
        """None until the window has samples spanning at least half of it."""
        while self._samples and self._samples[0][0] < now - self.window_s:
            self._samples.popleft()
        if len(self._samples) < 2 or now - self._samples[0][0] < self.window_s / 2:
            return None
        return sum(b for _, b in self._samples) / (now - self._samples[0][0])
