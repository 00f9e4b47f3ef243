"""What every force sensor does to its raw readings, in this order: low-pass filter,
tare (bias), threshold. Shared by the simulated and the real sensors."""

from __future__ import annotations

import math

from telerobot.drivers.base import InvalidCommand

Six = tuple[float, float, float, float, float, float]
ZERO: Six = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


class ForcePipeline:
    def __init__(self, rate_hz: float = 1000.0) -> None:
        self.rate_hz = rate_hz
        self.threshold = 0.0
        self.filter_cutoff_hz: float | None = None
        self._filtered: Six | None = None
        self._bias: Six = ZERO
        self._last_reported: Six | None = None
        self._tare_requested = False

    @staticmethod
    def check_rate(rate_hz: float) -> float:
        if not (
            isinstance(rate_hz, int | float)
            and math.isfinite(rate_hz)
            and 1.0 <= rate_hz <= 10_000.0
        ):
            raise InvalidCommand(f"sample rate must be 1–10000 Hz, got {rate_hz!r}")
        return float(rate_hz)

    @staticmethod
    def check_threshold(threshold: float) -> float:
        if not (isinstance(threshold, int | float) and math.isfinite(threshold) and threshold >= 0):
            raise InvalidCommand(f"threshold must be a finite number ≥ 0, got {threshold!r}")
        return float(threshold)

    @staticmethod
    def check_cutoff(cutoff: float | None, rate_hz: float) -> float | None:
        if cutoff is None:
            return None
        if not (
            isinstance(cutoff, int | float) and math.isfinite(cutoff) and 0 < cutoff < rate_hz / 2
        ):
            raise InvalidCommand(
                f"filter cut-off must be between 0 and half the sample rate ({rate_hz / 2:g} Hz)"
            )
        return float(cutoff)

    def tare(self) -> None:
        """The next reading becomes the zero."""
        self._tare_requested = True

    def process(self, raw: Six) -> Six | None:
        """The reading to report, or None when the threshold withholds it."""
        if self.filter_cutoff_hz is None or self._filtered is None:
            filtered = raw
        else:
            dt = 1.0 / self.rate_hz
            rc = 1.0 / (2.0 * math.pi * self.filter_cutoff_hz)
            a = dt / (rc + dt)
            filtered = tuple(f + a * (r - f) for f, r in zip(self._filtered, raw, strict=True))  # type: ignore[assignment]
        self._filtered = filtered
        if self._tare_requested:
            self._bias, self._tare_requested = filtered, False
            self._last_reported = None
        out: Six = tuple(f - b for f, b in zip(filtered, self._bias, strict=True))  # type: ignore[assignment]
        last = self._last_reported
        if (
            self.threshold > 0
            and last is not None
            and max(abs(o - p) for o, p in zip(out, last, strict=True)) <= self.threshold
        ):
            return None
        self._last_reported = out
        return out
