"""A token bucket per connection: how many messages a client may send per second.

The operator's page sends ≤ 100 commands and heartbeats a second, the master-arm
bridge 100 Hz of increments plus pings; a client that sends much more is a bug or an
attack and must not take the event loop (the e-stop's, the dead-man's) from the
others. Over budget, the connection's reader waits for the next token: TCP then
pushes back on the sender, nothing is queued here. A client that goes on sending
nothing but malformed messages is closed.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

MESSAGES_PER_S = 1000.0  # 10× what any real client sends
BURST = 500  # messages that may come back to back (a page catching up after a stall)
MALFORMED_IN_A_ROW = 200  # nothing but garbage this long: the client is closed
# A malformed message costs this many tokens (decoding it and writing the ERROR cost
# the loop more than a command does): garbage flows at 1/10 of the rate at most.
MALFORMED_COST = 10.0


@dataclass
class TokenBucket:
    rate: float = MESSAGES_PER_S
    burst: float = BURST
    at: float | None = None
    throttled: int = 0  # messages that had to wait
    tokens: float = field(init=False)

    def __post_init__(self) -> None:
        self.tokens = self.burst

    def take(self, now: float, cost: float = 1.0) -> float:
        """Take ``cost`` tokens; the seconds to wait first (0 when they were there)."""
        if self.at is not None:
            self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        self.tokens -= cost
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


CONNECTIONS_PER_S = 10.0  # new /ws connections a second from one address…
CONNECTION_BURST = 50  # …after a burst (a page reloading, a test suite)
MAX_PEERS = 1024  # addresses remembered; the one heard from longest ago goes first


@dataclass
class PeerLimits:
    """Budgets per remote address, shared by all its connections: a client that is
    closed for flooding and reconnects gets no fresh burst, and reconnecting itself is
    rate-limited. The table is bounded (least recently seen address dropped)."""

    messages_per_s: float = MESSAGES_PER_S
    burst: float = BURST
    connections_per_s: float = CONNECTIONS_PER_S
    connection_burst: float = CONNECTION_BURST
    max_peers: int = MAX_PEERS
    _peers: OrderedDict[str, tuple[TokenBucket, TokenBucket]] = field(default_factory=OrderedDict)
    refused_connections: int = 0

    def _buckets(self, peer: str) -> tuple[TokenBucket, TokenBucket]:
        buckets = self._peers.pop(peer, None)
        if buckets is None:
            buckets = (
                TokenBucket(self.messages_per_s, self.burst),
                TokenBucket(self.connections_per_s, self.connection_burst),
            )
        self._peers[peer] = buckets
        while len(self._peers) > self.max_peers:
            self._peers.popitem(last=False)
        return buckets

    def connect(self, peer: str, now: float) -> TokenBucket | None:
        """The address's message budget, or None when it connects too often."""
        messages, connections = self._buckets(peer)
        if connections.take(now) > 0:
            connections.tokens += 1.0  # refused: the attempt costs nothing more
            self.refused_connections += 1
            return None
        return messages

    def charge(self, peer: str, now: float, cost: float) -> None:
        """Take ``cost`` more connections' worth from the address's budget, into debt if
        need be (what a connection turned out to cost: its next ones wait for it)."""
        self._buckets(peer)[1].take(now, cost)
