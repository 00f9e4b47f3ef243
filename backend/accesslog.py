"""The access log under a flood of refused requests.

uvicorn logs one line per request. A client repeating a request the server refuses
(429 past a budget, 403 without the token, 404, 413…) writes a line per refusal: one
tokenless loop in ``bench.abuse`` wrote 2,100 lines in 10 s, which over a day fills a
disk, and each line is a write on the event loop that also serves the e-stop. So per
client address the first ``per_window`` refusals of each ``window_s`` are logged as
they come, and the rest are counted: a line says when an address reaches the limit, and
how many were not logged once it is heard from in a later window. (uvicorn's access
formatter prints a record's arguments, not its message: the notes are lines of their
own.) Answered requests (below 400) and server errors (500 and up: ours
to fix) are always logged.
"""

from __future__ import annotations

import logging
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)

WINDOW_S = 10.0
REFUSALS_PER_WINDOW = 20
MAX_ADDRESSES = 1024  # addresses remembered; the one heard from longest ago goes first


@dataclass
class _Window:
    start: float
    logged: int = 0
    held: int = 0  # refusals not logged in this window


class RefusalLogLimit(logging.Filter):
    """A filter for uvicorn's access logger (its records' args: client address, method,
    path, HTTP version, status)."""

    def __init__(
        self,
        per_window: int = REFUSALS_PER_WINDOW,
        window_s: float = WINDOW_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__()
        self.per_window = per_window
        self.window_s = window_s
        self.clock = clock
        self.held_total = 0  # refusals not logged, all addresses, so far
        self._windows: OrderedDict[str, _Window] = OrderedDict()

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        if not isinstance(args, tuple) or len(args) < 5:
            return True
        status = args[4]
        if not isinstance(status, int) or not 400 <= status < 500:
            return True
        address = str(args[0]).rsplit(":", 1)[0]  # "ip:port": one budget per machine
        now = self.clock()
        window = self._windows.pop(address, None)
        if window is None or now - window.start >= self.window_s:
            if window is not None and window.held:
                log.warning(
                    "%d more refused requests from %s were not logged", window.held, address
                )
            window = _Window(now)
        self._windows[address] = window
        while len(self._windows) > MAX_ADDRESSES:
            self._windows.popitem(last=False)
        if window.logged >= self.per_window:
            window.held += 1
            self.held_total += 1
            return False
        window.logged += 1
        if window.logged == self.per_window:
            log.warning(
                "%d refusals from %s within %g s: more in this time are counted, not logged",
                self.per_window, address, self.window_s,
            )  # fmt: skip
        return True


def limit_refusals_logged() -> None:
    """Install the limit on uvicorn's access logger (once; after uvicorn set it up)."""
    logger = logging.getLogger("uvicorn.access")
    if not any(isinstance(f, RefusalLogLimit) for f in logger.filters):
        logger.addFilter(RefusalLogLimit())
