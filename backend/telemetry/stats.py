"""Rolling statistics of one stream: the last N values, percentiles, a histogram.

``record`` is O(1) and allocation-free so it can sit on a 1 kHz path; the summary
is computed only when someone asks.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Summary:
    name: str
    unit: str
    count: int  # values recorded since start
    window: int  # values the figures below are computed over
    mean: float
    p50: float
    p99: float
    max: float
    histogram_edges: list[float]
    histogram_counts: list[int]


@dataclass
class DriftingFloor:
    """The least of a stream of values (a transit time, a round trip) that rises by
    ``drift`` per second of ``now`` since it was last lowered: a delay that grew for good
    is followed, a short dip does not stay the floor for ever."""

    drift: float
    value: float | None = None
    at: float = 0.0

    def update(self, x: float, now: float) -> float:
        """The floor with ``x`` seen at ``now``."""
        floor = self.value
        if floor is not None:
            floor += (now - self.at) * self.drift
        if floor is None or x < floor:
            floor = x
        self.value, self.at = floor, now
        return floor


class StreamStats:
    def __init__(self, name: str, unit: str = "ms", capacity: int = 10_000) -> None:
        self.name = name
        self.unit = unit
        self._values = np.zeros(capacity)
        self._n = 0
        self._lock = threading.Lock()

    def record(self, value: float) -> None:
        with self._lock:
            self._values[self._n % len(self._values)] = value
            self._n += 1

    @property
    def count(self) -> int:
        return self._n

    def values(self) -> np.ndarray:
        with self._lock:
            n = min(self._n, len(self._values))
            if self._n <= len(self._values):
                return self._values[:n].copy()
            start = self._n % len(self._values)
            return np.concatenate([self._values[start:], self._values[:start]])

    def summary(self, bins: int = 30) -> Summary:
        v = self.values()
        if len(v) == 0:
            return Summary(
                self.name, self.unit, 0, 0, math.nan, math.nan, math.nan, math.nan, [], []
            )
        counts, edges = np.histogram(v, bins=bins)
        return Summary(
            self.name,
            self.unit,
            self._n,
            len(v),
            float(v.mean()),
            float(np.percentile(v, 50)),
            float(np.percentile(v, 99)),
            float(v.max()),
            edges.tolist(),
            counts.tolist(),
        )


class StreamTally(StreamStats):
    """A StreamStats that also keeps, over every value since its start (not only the
    window the percentiles are of), the largest and how many were above ``limit``:
    a rolling window forgets its worst value, and these must not."""

    def __init__(
        self, name: str, unit: str = "ms", capacity: int = 10_000, *, limit: float
    ) -> None:
        super().__init__(name, unit, capacity)
        self.limit = limit
        self._largest = -math.inf
        self._over = 0

    def record(self, value: float) -> None:
        with self._lock:
            self._values[self._n % len(self._values)] = value
            self._n += 1
            if value > self._largest:
                self._largest = value
            if value > self.limit:
                self._over += 1

    @property
    def capacity(self) -> int:
        return len(self._values)

    @property
    def largest(self) -> float:
        """The largest value since the start (NaN before the first)."""
        return self._largest if self._n else math.nan

    @property
    def over(self) -> int:
        """How many values since the start were above ``limit``."""
        return self._over


class InterArrival(StreamStats):
    """Time between consecutive events, in milliseconds."""

    def __init__(self, name: str, capacity: int = 10_000) -> None:
        super().__init__(name, "ms", capacity)
        self._last: float | None = None

    def tick(self, t: float) -> None:
        if self._last is not None:
            self.record((t - self._last) * 1000.0)
        self._last = t


class Telemetry:
    """Every stream's statistics, by name, for the telemetry API."""

    def __init__(self) -> None:
        self.streams: dict[str, StreamStats] = {}

    def interarrival(self, name: str) -> InterArrival:
        s = self.streams.setdefault(name, InterArrival(name))
        assert isinstance(s, InterArrival)
        return s

    def stats(self, name: str, unit: str = "ms") -> StreamStats:
        return self.streams.setdefault(name, StreamStats(name, unit))

    def summaries(self) -> list[Summary]:
        return [s.summary() for s in self.streams.values()]
