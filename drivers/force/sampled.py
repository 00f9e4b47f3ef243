"""What the simulated and the real force sensors share: the settings (rate, threshold,
filter), tare, subscribers, the newest sample, and the thread they sample in.

A subclass supplies ``_run`` (its sampling loop, which calls ``_deliver`` with each
raw reading) and may override ``tare`` (a real sensor biases itself)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Mapping

from telerobot.drivers.base import ForceSample
from telerobot.drivers.force.pipeline import ForcePipeline, Six
from telerobot.drivers.threads import WorkerThread

log = logging.getLogger(__name__)


class SampledForceSensor:
    name = "force"
    thread_name = "force-sensor"
    error: str | None = None  # what is wrong now; a simulated sensor has no faults

    @property
    def counters(self) -> Mapping[str, int]:
        """The driver's counters (received, lost …); none unless a subclass keeps some."""
        return {}

    def __init__(self, rate_hz: float) -> None:
        self._pipeline = ForcePipeline(ForcePipeline.check_rate(rate_hz))
        self._lock = threading.Lock()  # pipeline settings vs the sampling thread
        self._subscribers: list[Callable[[ForceSample], None]] = []
        self._latest: ForceSample | None = None
        self._worker = WorkerThread(self._run, self.thread_name, prompt=True)
        self._stop = self._worker.stopping

    # ------------------------------------------------------------ settings
    @property
    def rate_hz(self) -> float:
        return self._pipeline.rate_hz

    @rate_hz.setter
    def rate_hz(self, value: float) -> None:
        rate = ForcePipeline.check_rate(value)
        with self._lock:
            self._pipeline.rate_hz = rate
            if (
                self._pipeline.filter_cutoff_hz is not None
                and self._pipeline.filter_cutoff_hz >= rate / 2
            ):
                self._pipeline.filter_cutoff_hz = None

    @property
    def threshold(self) -> float:
        return self._pipeline.threshold

    @threshold.setter
    def threshold(self, value: float) -> None:
        self._pipeline.threshold = ForcePipeline.check_threshold(value)

    @property
    def filter_cutoff_hz(self) -> float | None:
        return self._pipeline.filter_cutoff_hz

    @filter_cutoff_hz.setter
    def filter_cutoff_hz(self, value: float | None) -> None:
        with self._lock:
            self._pipeline.filter_cutoff_hz = ForcePipeline.check_cutoff(
                value, self._pipeline.rate_hz
            )

    def tare(self) -> None:
        with self._lock:
            self._pipeline.tare()

    # ------------------------------------------------------------ samples
    @property
    def latest(self) -> ForceSample | None:
        return self._latest

    def subscribe(
        self, callback: Callable[[ForceSample], None], *, first: bool = False
    ) -> Callable[[], None]:
        # Copy-on-write: the sampling thread iterates the old list safely.
        others = self._subscribers
        self._subscribers = [callback, *others] if first else [*others, callback]

        def unsubscribe() -> None:
            self._subscribers = [c for c in self._subscribers if c is not callback]

        return unsubscribe

    def _deliver(self, seq: int, t: float, raw: Six) -> ForceSample | None:
        """Filter, tare and threshold ``raw``; hand the result to every subscriber."""
        with self._lock:
            values = self._pipeline.process(raw)
        if values is None:
            return None
        sample = ForceSample(seq, t, values)
        self._latest = sample
        for callback in self._subscribers:
            try:
                callback(sample)
            except Exception:  # one subscriber's bug must not stop the sensor
                log.exception("force subscriber failed")
        return sample

    # ------------------------------------------------------------ thread
    @property
    def running(self) -> bool:
        return self._worker.running

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()

    def _run(self) -> None:
        raise NotImplementedError
