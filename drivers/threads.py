"""The one thread every sampling, capture and device loop here runs in."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

log = logging.getLogger(__name__)


class WorkerThread:
    """A daemon thread running ``target`` until ``stop()``; ``target`` watches
    ``stopping`` (an Event, so it can also ``stopping.wait(t)`` instead of sleeping)."""

    def __init__(self, target: Callable[[], None], name: str, *, prompt: bool = False) -> None:
        self.target = target
        self.name = name
        self.prompt = prompt  # a 1 kHz loop: realtime or short slices (tuning.prompt_thread)
        self.stopping = threading.Event()
        self._prompted = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self.stopping.clear()
        self._prompted.clear()
        self._thread = threading.Thread(target=self._main, name=self.name, daemon=True)
        self._thread.start()
        if self.prompt:  # what it got is known when start returns (the server says it)
            self._prompted.wait(1.0)

    def _main(self) -> None:
        if self.prompt:
            from telerobot.tuning import prompt_thread

            log.debug("%s runs %s", self.name, prompt_thread())
            self._prompted.set()
        self.target()

    def stop(self, timeout: float = 2.0) -> None:
        self.stopping.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout)
            self._thread = None
