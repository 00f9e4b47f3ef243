"""Forces as UDP datagrams (DATAGRAMS; docs/protocol.md), the priority channel's UDP
side: the socket on the channel's port, a client's registration on TCP (a new key of
the server's), the datagrams that fix its address, and each FORCE sent with a token
bucket per client.

For operators only, and only to the IP address of the client's own TCP connection:
UDP can be sent from a forged source, TCP cannot (priority.py's docstring has the
bounds). The per-client fields live on ``PriorityClient`` (priority_connection.py),
under its lock."""

from __future__ import annotations

import logging
import math
import secrets
import socket
import time
from collections.abc import Callable
from typing import Any

from telerobot.protocol import messages as m
from telerobot.protocol.netprio import mark_high_priority
from telerobot.protocol.typed import DatagramsMessage, parse
from telerobot.server.control.arm_guard import arm_sensors
from telerobot.server.control.decision import DecisionServer
from telerobot.server.realtime.priority_connection import PriorityClient
from telerobot.server.realtime.ratelimit import TokenBucket
from telerobot.server.realtime.session import error

log = logging.getLogger(__name__)

# Module constants, as priority.py's limits (they protect the server from its clients).
# Back to TCP after this long without a datagram from the client (it sends one at
# least every second).
DATAGRAM_TIMEOUT_S = 2.0
MAX_EVERY = 1000  # DATAGRAMS.every: at least one sample a second
MAX_DATAGRAMS_PER_STEP = 64  # read at once; a UDP flood then waits behind the TCP clients
# What one client may be sent as datagrams: the sensor's samples at its ``every``, with
# this much slack for a sensor's jitter, in bursts of this long (a network sensor's
# samples can arrive bunched after a hiccup; older than that, lost beats late).
DATAGRAM_RATE_SLACK = 1.25
DATAGRAM_BURST_S = 0.05
DEFAULT_FORCE_RATE_HZ = 1000.0  # a sensor that does not say its rate (ForceSensor.rate_hz)


class ForceDatagrams:
    """The UDP side of one priority channel. ``register`` and ``forget`` run on the
    event loop, ``read`` on the channel's thread, ``offer`` on the sensor's."""

    def __init__(
        self,
        host: str,
        port: int,
        decision: DecisionServer,
        log_limited: Callable[..., None],
    ) -> None:
        self.decision = decision
        self._log_limited = log_limited
        self.sock = self._socket(host, port)
        # DATAGRAMS keys → their client (at most one key per client, so as bounded as
        # the connections).
        self.keys: dict[bytes, PriorityClient] = {}
        self.sent = 0  # force samples sent as UDP datagrams
        # UDP datagrams refused: no registered key, or not from the key's client's IP
        # address (a forged source) or its first port.
        self.refused = 0
        self.over_rate = 0  # samples not sent: past a client's rate (bucket)

    def _socket(self, host: str, port: int) -> socket.socket | None:
        """A UDP socket on the channel's port number, for forces as datagrams; None
        (and DATAGRAMS refused) if that port is taken for UDP."""
        udp = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        try:
            udp.bind((host, port))
        except OSError as exc:
            udp.close()
            log.warning("no UDP port %d for forces as datagrams (%s): TCP only", port, exc)
            return None
        udp.setblocking(False)
        mark_high_priority(udp)
        return udp

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()

    # ------------------------------------------------------------ the event loop
    def register(self, client: PriorityClient, message: bytes) -> bytes:
        """DATAGRAMS on the client's TCP socket (on the event loop): the reply, with a
        new key (the old one, and the address learnt with it, no longer count)."""
        asked = parse(message)
        if not isinstance(asked, DatagramsMessage):  # (``_serve`` sends only those here)
            raise m.MalformedMessage(f"{asked.SPEC.name} is not DATAGRAMS")
        seq, every = asked.seq, asked.every
        if not 1 <= every <= MAX_EVERY:
            return error(seq, "invalid_command", f"every must be 1 to {MAX_EVERY}")
        if self.sock is None:
            return error(seq, "not_ready", "this server has no UDP port: forces stay on TCP")
        if client.session is None or not client.session.conn.operator:
            # UDP has no handshake: whatever an unauthenticated client could start would
            # be sent at someone, so it gets its forces on TCP only.
            return error(
                seq,
                "not_allowed",
                "forces as datagrams are for operators (the operator token):"
                " an observer gets them on TCP",
            )
        key = secrets.token_bytes(16)
        with client.lock:
            old, client.datagram_key = client.datagram_key, key
            client.datagram_addr = None
            client.datagram_every = every
            client.datagram_heard = -math.inf
        if old is not None:
            self.keys.pop(old, None)
        self.keys[key] = client
        return DatagramsMessage(seq=seq, key=key, every=every).encode()

    def forget(self, client: PriorityClient) -> None:
        if client.datagram_key is not None:
            self.keys.pop(client.datagram_key, None)
        client.datagram_addr = None

    # ------------------------------------------------------------ the channel's thread
    def read(self) -> None:
        """DATAGRAMS from the clients' UDP sockets: where their forces go from now on.
        Anything else is dropped unanswered (no reply: a forged source address gets
        nothing back), and so is a datagram with a client's key from anywhere but that
        client's TCP address (the IP; the port its first one came from): UDP's source
        can be forged, and the key crosses the network in clear."""
        assert self.sock is not None
        for _ in range(MAX_DATAGRAMS_PER_STEP):
            try:
                data, addr = self.sock.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # (an ICMP error reported on the socket)
            client = None
            if len(data) == m.DATAGRAMS.size and data[0] == m.DATAGRAMS.type_id:
                _, _, key, every = m.DATAGRAMS.struct.unpack(data)
                client = self.keys.get(key) if 1 <= every <= MAX_EVERY else None
            if client is None or client.closed or addr[0] != client.host:
                self.refused += 1
                continue
            with client.lock:  # (against a new registration on the event loop)
                if client.datagram_key != key or client.datagram_addr not in (None, addr):
                    self.refused += 1
                    continue
                if client.datagram_addr is None:
                    log.info("priority client %s: forces as datagrams to %s", client.peer, addr)
                client.datagram_addr = addr
                client.datagram_every = every
                client.datagram_bucket = self._bucket(every, client.datagram_bucket)
                client.datagram_heard = time.monotonic()

    def _bucket(self, every: int, bucket: TokenBucket | None) -> TokenBucket:
        """The bucket for ``every``: the same one (its tokens kept) if the rate holds.
        Every arm's sensor sends the client its samples: the rate is theirs together
        (sized for one, it dropped half of two arms' samples as over the rate)."""
        rate_hz = sum(
            float(getattr(sensor, "rate_hz", None) or DEFAULT_FORCE_RATE_HZ)
            for _, sensor in arm_sensors(self.decision.arms)
        ) or float(DEFAULT_FORCE_RATE_HZ)
        rate = DATAGRAM_RATE_SLACK * rate_hz / every
        if bucket is not None and bucket.rate == rate:
            return bucket
        return TokenBucket(rate, max(2.0, rate * DATAGRAM_BURST_S))

    # ------------------------------------------------------------ the sensor's thread
    def offer(self, client: PriorityClient, message: bytes, addr: Any, now: float) -> None:
        """One FORCE for a client that takes its forces as datagrams, if its bucket
        allows (the sensor's thread takes from it, alone)."""
        bucket = client.datagram_bucket
        if bucket is not None and bucket.take(now) > 0:
            self.over_rate += 1  # a burst past its rate: lost, not late
            bucket.tokens += 1  # (not taken: a refused one costs nothing)
        else:
            self.send(client, message, addr)

    def send(self, client: PriorityClient, message: bytes, addr: Any) -> None:
        assert self.sock is not None  # (an address is only learnt through it)
        try:
            self.sock.sendto(message, addr)
            self.sent += 1
        except (BlockingIOError, InterruptedError):
            client.forces_dropped += 1  # the socket's buffer is full: this one is lost
        except OSError as exc:  # (unreachable, …): TCP until the client says otherwise
            client.datagram_addr = None
            self._log_limited("datagram", "forces to %s as datagrams failed: %s", addr, exc)
