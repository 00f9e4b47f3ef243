"""What one viewer's NACKs may cost the server (docs/architecture.md, "Media"): resends
within a budget of bytes a second tied to the rate of the layer it watches, as
libwebrtc's retransmission rate limiter does, and each packet resent at most once a
round trip (libwebrtc's packet history waits a round trip too). A viewer that asks for
more is not answered: its picture may freeze, every other viewer's goes on.

Without it one tokenless viewer asking 200 times a second for the 128 newest packets
got 3.9 MB/s of resends for 18.6 kB/s of NACKs (×204), and the shared encoder, on the
same event loop as the resends, fell to 4.6 frames/s for every viewer.

Time is passed in (``now``): tested on made-up clocks."""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

# A second's budget is this share of the viewer's layer rate, as libwebrtc limits its
# retransmissions to the target rate: a lossy link's repairs fit; a flood does not.
# (Half of it, with a 200 kbit/s floor and half a second of burst, refused 182 of a
# `bad` link's 275 repairs in one run: a lost key frame is tens of packets at once.)
RESEND_SHARE = 1.0
BURST_S = 1.0  # the bucket holds this many seconds of budget (a cut's burst of NACKs)
FLOOR_BPS = 1_000_000  # the budget's floor, should the layer's rate be unknown or low
MIN_GAP_S = 0.02  # resent again no sooner than this, whatever the round trip says
DEFAULT_RTT_S = 0.1  # before the receiver's reports give one
REMEMBERED = 1024  # packets whose last resend is remembered (aiortc keeps 128 to resend)


@dataclass
class ResendCounts:
    resent: int = 0
    bytes_resent: int = 0
    over_budget: int = 0  # asked for and not resent: the budget was spent
    too_soon: int = 0  # asked for again within a round trip of its last resend


class ResendBudget:
    """One viewer's resends: ``allow(key, size, rtt_s, now)`` says whether to resend
    the packet ``key`` of ``size`` bytes now, and if so spends its bytes."""

    def __init__(
        self,
        rate_bps: Callable[[], float | None],
        share: float = RESEND_SHARE,
        burst_s: float = BURST_S,
    ) -> None:
        self._rate_bps = rate_bps
        self.share = share
        self.burst_s = burst_s
        self._tokens: float | None = None  # bytes; full at the first ask
        self._at = 0.0
        self._last: OrderedDict[object, float] = OrderedDict()
        self.counts = ResendCounts()

    def bytes_per_s(self) -> float:
        return max(FLOOR_BPS, self._rate_bps() or 0.0) * self.share / 8

    def allow(self, key: object, size: int, rtt_s: float | None, now: float) -> bool:
        per_s = self.bytes_per_s()
        full = per_s * self.burst_s
        if self._tokens is None:
            self._tokens = full
        else:
            self._tokens = min(full, self._tokens + per_s * max(0.0, now - self._at))
        self._at = now
        last = self._last.get(key)
        if last is not None and now - last < max(MIN_GAP_S, rtt_s or DEFAULT_RTT_S):
            self.counts.too_soon += 1
            return False
        if self._tokens < size:
            self.counts.over_budget += 1
            return False
        self._tokens -= size
        self._last[key] = now
        self._last.move_to_end(key)
        while len(self._last) > REMEMBERED:
            self._last.popitem(last=False)
        self.counts.resent += 1
        self.counts.bytes_resent += size
        return True

    def as_dict(self) -> dict[str, float | int]:
        c = self.counts
        return {
            "budget_bytes_per_s": round(self.bytes_per_s()),
            "resent": c.resent,
            "bytes_resent": c.bytes_resent,
            "over_budget": c.over_budget,
            "too_soon": c.too_soon,
        }
