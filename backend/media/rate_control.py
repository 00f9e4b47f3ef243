"""The operator's own video rate: a congestion estimate of the operator's link, and
the bitrate, size and frame rate of the encoder that serves the operator alone
(docs/architecture.md, "Media").

Watchers share the layered stream (layers.py): one encode per layer, each viewer moved
between layers by its link. The operator cannot wait for that: on a narrow link (the
`bad` profile, 2 Mbit/s shared with the forces) the shared layer's rate is whatever the
scene makes of the configured bitrate, FEC did not fit beside it and was switched off,
and the picture froze. So the operator's peer gets an encoder of its own whose rate
follows an estimate of its own link, the way a libwebrtc sender's does (GCC, Holmer et
al., draft-ietf-rmcat-gcc), from what its receiver reports over RTCP about once a
second:

* **loss-based**: a report losing more than ``HIGH_LOSS`` cuts the rate by half the
  loss (``rate × (1 − loss/2)``); one losing less than ``LOW_LOSS`` with no queue lets
  it grow by ``INCREASE`` a second; in between it holds (a lossy but uncongested
  link, as `bad`'s 5 % random loss, is FEC's to repair, not the rate's). A report's
  loss is the mean of the last ``LOSS_WINDOW_S``'s reports, and the rate is cut at
  most once a round trip (``CUT_GAP_S`` at least): Chromium's reports come ten a
  second on `bad` (one in each NACK), each of a few packets, and one losing one of
  four had cut the rate to its 150 kbit/s floor, where the loss held it for good.
  (Growing through the link's own loss, the median of recent reports, was tried: on
  `bad` the rate grew into the link's queue, the round trip to 0.6–0.8 s, and every
  repair came too late for the playout delay.)
* **delay-based**: the round trip grown ``QUEUE_S`` above its floor in
  ``CONFIRM_REPORTS`` reports in a row is a queue the video builds: ``× DECREASE``;
* **the receiver's own estimate** (REMB, from Chromium's delay-gradient estimator):
  with heavy loss (above ``HIGH_LOSS``) the rate goes straight to it if it is lower
  (what gets through); otherwise it leads the rate down, ``× DECREASE`` a cut at most,
  once it has fallen from its peak (``ESTIMATE_FALL``) in ``CONFIRM_REPORTS``
  reports in a row while the round trip has begun to grow (``EARLY_QUEUE_S`` above its
  floor): a receiver starts low and climbs, so a low estimate that is still rising says
  nothing (as in layers.py), and on a jittery link it swings far below what the link
  carries with no queue behind it (`bad`, ±50 ms each way: Chromium's fell to
  0.05 Mbit/s on a 2 Mbit/s link, the rate followed to its floor, and at 150 kbit/s a
  key frame took the link for a second: the picture was frozen two thirds of the
  time).

A new peer starts at ``START_BPS`` (or the configured bitrate, if lower), not at the
top: nothing is known of its link yet, and 8 Mbit/s sent into a 2 Mbit/s link with a
deep queue (`bad`'s: 1000 packets, seconds of it) delays everything behind it, the
forces and the commands too, for as long as the estimate takes to come down (quiet
runs of bench.wan saw the page's peer start at 6.8 Mbit/s there, stall and never show
a picture). Until its link first shows congestion (the start-up, as GCC's slow start
and libwebrtc's probes) a clean second grows it by ``STARTUP_INCREASE``, so a clean
link is back at the top in a few seconds; from the first congestion on, by
``INCREASE``.

The rate stays within [``MIN_BPS``, the configured bitrate]. Out of it come FEC's
share and a margin for resends (``media_bps``), so FEC fits inside the estimate
instead of being switched off. Below what the full size needs (``MIN_BITS_PER_PIXEL``)
the encoder drops to the low layer's size, and below what that size needs at the full
frame rate, to half the frame rate; each comes back only with ``UP_MARGIN`` to spare.
While the rate is the configured bitrate the operator's peer stays on the shared full
layer (the same stream, one encode less: on a clean link nothing changes); it gets its
own encoder at the first cut, and shares again once back at the top for
``SHARE_AGAIN_S``. Pure: time is passed in, the pipeline calls ``update`` on each fresh
report.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from telerobot.server.media.layers import LinkReport
from telerobot.server.telemetry.stats import DriftingFloor

MIN_BPS = 150_000
HIGH_LOSS = 0.10
LOW_LOSS = 0.02
# A report's loss is the mean of those of the last second: each of Chromium's reports
# (10 a second on `bad`, one in each NACK) covers a few packets, one lost of four is
# 25 %, and one such report had cut the rate to the receiver's estimate (GCC waits
# for 20 packets' worth).
LOSS_WINDOW_S = 1.0
INCREASE = 1.08  # a clean second's growth (GCC's multiplicative increase)
START_BPS = 1_000_000  # a new peer's rate: what a narrow link (2 Mbit/s with the forces) carries
STARTUP_INCREASE = 1.5  # a clean second's growth until the link first shows congestion
DECREASE = 0.85  # a queue's cut
CUT_GAP_S = 0.5  # one cut at most in this long, or a round trip if longer
QUEUE_S = 0.15  # the round trip this far above its floor: a queue (jitter stays below)
EARLY_QUEUE_S = 0.075  # …this far: one beginning, which a fallen estimate confirms
CONFIRM_REPORTS = 2  # a queue seen in this many reports in a row (one late RTCP is not)
ESTIMATE_FALL = 0.85  # the receiver's estimate this far below its peak: it saw overuse
FLOOR_DRIFT = 0.01  # s per s: the round trip's floor follows a link whose delay grew
RESEND_SHARE = 0.1  # of the rate, kept for resends (resend_budget.py spends it)
# Below this many bits per pixel x264 (ultrafast) turns to blocks: the smaller size
# then looks better at the same rate.
MIN_BITS_PER_PIXEL = 0.03
UP_MARGIN = 1.3  # back to a bigger size or rate only with this much to spare
FULL_SIZE_SHARE = 0.7  # of the configured bitrate: below it, never the full size…
FULL_RATE_SHARE = 0.35  # …and never the full frame rate below this
# Back at the configured rate this long: the operator shares the full layer again.
SHARE_AGAIN_S = 10.0


@dataclass
class RateControl:
    """One operator's link estimate and the encoder settings that follow it.

    ``full_pixels`` and ``low_pixels``: one frame's pixels (both eyes) at the full and
    the low size; ``fps``: the configured frame rate."""

    max_bps: int
    full_pixels: int
    low_pixels: int
    fps: float
    start_bps: int = START_BPS  # a new peer's rate (the configured one, if lower)
    target_bps: float = 0.0
    size: str = "full"  # "full" or "low"
    every: int = 1  # encode every n-th frame
    why: str = "start: nothing known of the link yet"
    seen_reports: int = 0
    last_report_at: float | None = None  # (the caller's clock)
    last_cut_at: float = -math.inf
    queue_strikes: int = 0
    estimate_strikes: int = 0  # reports in a row whose estimate had fallen
    peak_estimate: int = 0
    cuts: int = 0
    starting: bool = True  # no congestion seen yet: growing by STARTUP_INCREASE
    # (the caller's clock) at the configured rate since (None: below it)
    at_max_since: float | None = None
    floor: DriftingFloor = field(default_factory=lambda: DriftingFloor(FLOOR_DRIFT))
    # (time, loss) of the reports of the last LOSS_WINDOW_S (at most 100 kept)
    window: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=100))

    def __post_init__(self) -> None:
        self.max_bps = max(self.max_bps, MIN_BPS)
        self.target_bps = float(min(self.max_bps, max(MIN_BPS, self.start_bps)))
        if self.target_bps >= self.max_bps:
            self.at_max_since = -math.inf
        self._shape()

    def update(self, link: LinkReport, loss: float | None, now: float) -> bool:
        """A receiver report more (``loss``: the share its NACKs show lost, which a
        receiver report hides once resent; the larger of the two counts). True if the
        rate, size or frame rate changed."""
        if link.reports <= self.seen_reports:
            return False
        self.seen_reports = link.reports
        # Growth is by the second, not by the report: Chromium's NACKs and REMBs each
        # carry a receiver report (10 a second on `bad`), and a rate grown ×1.08 at
        # each filled the link's 1000-packet queue in seconds (bench.wan: the command
        # client's HELLO waited behind it for 5 s).
        since = (
            1.0 if self.last_report_at is None else min(1.0, max(0.0, now - self.last_report_at))
        )
        self.last_report_at = now
        before = (round(self.target_bps), self.size, self.every)
        self.window.append((now, max(link.fraction_lost or 0.0, loss or 0.0)))
        while self.window and self.window[0][0] <= now - LOSS_WINDOW_S:
            self.window.popleft()
        lost = statistics.fmean(x for _, x in self.window)  # (this report's is in it)
        queued = growing = False
        if link.rtt_s is not None and link.rtt_s > 0:
            self.floor.update(link.rtt_s, now)
            least = self.floor.value
            queued = least is not None and link.rtt_s > least + QUEUE_S
            growing = least is not None and link.rtt_s > least + EARLY_QUEUE_S
        self.queue_strikes = self.queue_strikes + 1 if queued else 0
        estimate = link.estimated_bps
        if estimate is not None:
            self.peak_estimate = max(self.peak_estimate, estimate)
        fallen = (
            estimate is not None
            and estimate < self.target_bps
            and estimate < ESTIMATE_FALL * self.peak_estimate
            and growing
        )
        self.estimate_strikes = self.estimate_strikes + 1 if fallen else 0
        congested = lost > HIGH_LOSS or self.queue_strikes >= CONFIRM_REPORTS
        if congested or self.estimate_strikes >= CONFIRM_REPORTS:
            self.starting = False
        # One cut a round trip (at least CUT_GAP_S): what a cut does shows in the reports
        # a round trip later, and a queue draining, or a lossy second, seen again in
        # each of ten reports a second had cut ten times.
        gap = max(CUT_GAP_S, link.rtt_s or 0.0)
        if now - self.last_cut_at < gap and (congested or self.estimate_strikes >= CONFIRM_REPORTS):
            pass  # hold: the last cut has not shown yet
        elif lost > HIGH_LOSS and estimate is not None and estimate < self.target_bps:
            # Heavy loss, and the receiver says what gets through: go there at once (a
            # new peer at the configured rate, 8 Mbit/s, on a link of 2; cut by the
            # loss alone it took a minute to come down). A queue alone does not: on a
            # jittery link (`bad`) Chromium's estimate said 0.16 Mbit/s of 2, and the
            # rate took half a minute to grow back.
            self._set(
                estimate,
                f"congested ({self._congestion(lost, link)}): the receiver"
                f" gets {estimate / 1e6:.2f} Mbit/s",
            )
            self.queue_strikes = 0
        elif lost > HIGH_LOSS:
            self._set(self.target_bps * (1 - lost / 2), f"{lost:.0%} lost")
        elif self.queue_strikes >= CONFIRM_REPORTS:
            self._set(self.target_bps * DECREASE, self._congestion(lost, link))
            self.queue_strikes = 0
        elif self.estimate_strikes >= CONFIRM_REPORTS and estimate is not None:
            # Toward the estimate, a step at a time (× DECREASE at most a cut): even
            # with the round trip growing, a receiver's delay-gradient estimate on a
            # jittery link swings far below what the link carries.
            to = max(float(estimate), self.target_bps * DECREASE)
            self._set(to, f"the receiver's estimate fell to {estimate / 1e6:.2f} Mbit/s")
            self.peak_estimate = max(estimate, round(to))  # a new peak to fall from
        elif lost < LOW_LOSS and not queued and self.target_bps < self.max_bps:
            if self.starting:
                self._set(self.target_bps * STARTUP_INCREASE**since, "clean: starting up")
            else:
                self._set(self.target_bps * INCREASE**since, "clean: growing")
        self._shape()
        if self.target_bps < self.max_bps:
            self.at_max_since = None
        elif self.at_max_since is None:
            # At the top straight out of the start-up: the link never pushed back, the
            # shared full layer is the same stream at once (a LAN's operator runs a
            # second encode only for the start-up's few seconds).
            self.at_max_since = -math.inf if self.starting else now
        return before != (round(self.target_bps), self.size, self.every)

    def carry_on_from(self, bps: float, why: str) -> None:
        """Start from ``bps`` (the operator's previous peer's rate on the same link: a
        page that re-negotiates its video after a stall would start again at the
        configured rate on a link it had just found narrow)."""
        self._set(bps, why)
        self.starting = False  # the link was found already
        self.at_max_since = -math.inf if self.target_bps >= self.max_bps else None
        self._shape()

    def needs_own_stream(self, now: float) -> bool:
        """Whether the link needs the operator's own encoder: its rate is below the
        configured one, or came back to it less than ``SHARE_AGAIN_S`` ago. Otherwise
        the shared full layer is the same stream (one encode less)."""
        since = self.at_max_since
        return since is None or now - since < SHARE_AGAIN_S

    @staticmethod
    def _congestion(lost: float, link: LinkReport) -> str:
        if lost > HIGH_LOSS:
            return f"{lost:.0%} lost"
        return f"a queue: round trip {(link.rtt_s or 0.0) * 1000:.0f} ms"

    def _set(self, bps: float, why: str) -> None:
        bps = min(float(self.max_bps), max(float(MIN_BPS), bps))
        if bps < self.target_bps:
            self.cuts += 1
            self.last_cut_at = self.last_report_at if self.last_report_at is not None else 0.0
        self.target_bps, self.why = bps, why

    def media_bps(self, fec_share: float) -> int:
        """The encoder's bitrate: the rate less the resends' margin and FEC's share
        (``fec_share`` FEC packets per media packet)."""
        return max(MIN_BPS // 2, round(self.target_bps * (1 - RESEND_SHARE) / (1 + fec_share)))

    def _shape(self) -> None:
        """The size and frame rate the rate can carry (``MIN_BITS_PER_PIXEL``), with
        ``UP_MARGIN`` to spare before going back up. At the configured bitrate it is
        always the full size and rate (as the shared layer), whatever the pixels: each
        need is at most a share of it (``FULL_SIZE_SHARE``, ``FULL_RATE_SHARE``)."""
        rate, top = self.target_bps, float(self.max_bps)
        full_need = min(MIN_BITS_PER_PIXEL * self.full_pixels * self.fps, FULL_SIZE_SHARE * top)
        low_need = min(MIN_BITS_PER_PIXEL * self.low_pixels * self.fps, FULL_RATE_SHARE * top)
        if self.size == "full" and rate < full_need:
            self.size = "low"
        elif self.size == "low" and rate >= min(top, UP_MARGIN * full_need):
            self.size = "full"
        if self.size == "full":
            self.every = 1
        elif self.every == 1 and rate < low_need:
            self.every = 2
        elif self.every == 2 and rate >= min(top, UP_MARGIN * low_need):
            self.every = 1

    def as_dict(self) -> dict[str, Any]:
        return {
            "kbps": self.target_bps / 1000,
            "max_kbps": self.max_bps / 1000,
            "size": self.size,
            "fps": self.fps / self.every,
            "why": self.why,
            "cuts": self.cuts,
        }
