"""A tiny synchronous event hook, the thesis's component events (PUMARobotMoved …)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")
log = logging.getLogger(__name__)


class Event(Generic[T]):
    """Handlers are called in subscription order; one failing handler never stops the others."""

    def __init__(self, name: str) -> None:
        self.name = name
        self._handlers: list[Callable[[T], None]] = []

    def subscribe(self, handler: Callable[[T], None]) -> Callable[[], None]:
        self._handlers.append(handler)
        return lambda: self.unsubscribe(handler)

    def unsubscribe(self, handler: Callable[[T], None]) -> None:
        if handler in self._handlers:
            self._handlers.remove(handler)

    def emit(self, value: T) -> None:
        for handler in list(self._handlers):
            try:
                handler(value)
            except Exception:  # a subscriber's bug must not break the driver
                log.exception("handler for event %s failed", self.name)
