"""A token bucket per connection: how many messages a client may send per second.

The operator's page sends ≤ 100 commands and heartbeats a second, the master-arm
bridge 100 Hz of increments plus pings; a client that sends much more is a bug or an
attack and must not take the event loop (the e-stop's, the dead-man's) from the
others. Over budget, the connection's reader waits for the next token: TCP then
pushes back on the sender, nothing is queued here. A client that goes on sending
nothing but malformed messages is closed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

MESSAGES_PER_S = 1000.0  # 10× what any real client sends
BURST = 500  # messages that may come back to back (a page catching up after a stall)
MALFORMED_IN_A_ROW = 200  # nothing but garbage this long: the client is closed


@dataclass
class TokenBucket:
    rate: float = MESSAGES_PER_S
    burst: float = BURST
    at: float | None = None
    throttled: int = 0  # messages that had to wait
    tokens: float = field(init=False)

    def __post_init__(self) -> None:
        self.tokens = self.burst

    def take(self, now: float) -> float:
        """Take one token; the seconds to wait first (0 when one was there)."""
        if self.at is not None:
            self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        self.tokens -= 1.0
        if self.tokens >= 0.0:
            return 0.0
        self.throttled += 1
        return -self.tokens / self.rate


@dataclass
class MalformedRun:
    """Counts malformed messages in a row; a good one resets the count."""

    limit: int = MALFORMED_IN_A_ROW
    count: int = 0

    def note(self, malformed: bool) -> bool:
        """True when the client has sent ``limit`` malformed messages in a row."""
        self.count = self.count + 1 if malformed else 0
        return self.count >= self.limit
