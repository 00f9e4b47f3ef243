"""The one thread every sampling, capture and device loop here runs in."""

from __future__ import annotations

import threading
from collections.abc import Callable


class WorkerThread:
    """A daemon thread running ``target`` until ``stop()``; ``target`` watches
    ``stopping`` (an Event, so it can also ``stopping.wait(t)`` instead of sleeping)."""

    def __init__(self, target: Callable[[], None], name: str) -> None:
        self.target = target
        self.name = name
        self.stopping = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self.stopping.clear()
        self._thread = threading.Thread(target=self.target, name=self.name, daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 2.0) -> None:
        self.stopping.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
            self._thread = None
