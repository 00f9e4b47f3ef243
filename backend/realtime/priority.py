"""The priority channel: force samples out and commands in, on a TCP socket of their
own, for the master-arm bridge and any client that must feel forces on time.

Why not /ws: a WebSocket shares the server's event loop with everything else, and a
data channel would share the video's congestion control. Here every force sample is
written from the sensor's own thread the moment it is taken (no hop through the
event loop), and the socket is marked high priority (SO_PRIORITY 6, DSCP EF), so a
DiffServ-aware queue on the way sends it ahead of the video (which the media worker
marks low). Commands take the same path as /ws ones (``session.Session``: lease, limits,
dead-man), in order, on the event loop.

Framing: every message (layouts in ``messages``) is preceded by its length, u16
little-endian. The first message must be HELLO. Every force sample goes out as one
FORCE message with one sample (seq, sensor time, six values). A client that cannot
keep up loses the oldest queued samples, never the newest (counted per client).

Bounded at the edge (docs/architecture.md, rule 18; the values are the constants below):

- Connections: at most ``MAX_CONNECTIONS`` open (and never more than a quarter of
  RLIMIT_NOFILE), of which ``MAX_PENDING`` may still be waiting for HELLO. A new
  connection sheds the oldest one still waiting for HELLO; when every slot is taken
  by a client that has said HELLO, the new one gets ERROR ``limit_exceeded`` and is
  closed.
- HELLO within ``HELLO_TIMEOUT_S`` (else ERROR ``malformed``, closed). Nothing past
  the first message is read before it has been answered; what follows in the same
  write is read afterwards and handled in order.
- Messages: at most ``MAX_MESSAGE_BYTES`` each (else ERROR ``malformed``, closed);
  at most ``MAX_MESSAGES_PER_S`` per connection, in bursts of ``MAX_BURST`` (else
  ERROR ``limit_exceeded``, closed). Messages read and not yet handled: at most
  ``MAX_INBOX``; then the socket is not read (TCP pushes back on the client) until
  the event loop has caught up; likewise while ``REPLY_PAUSE`` replies wait for a
  client that does not read them.
- What waits to be sent: ``MAX_QUEUED_FORCES`` samples (the oldest dropped), one
  robot state (the newest), ``MAX_QUEUED_REPLIES`` replies (a client this far behind
  is closed).
- Forces as datagrams (DATAGRAMS; docs/protocol.md) are for operators only, and go
  only to the IP address of the client's own TCP connection: UDP can be sent from a
  forged source, TCP cannot, so a datagram from any other address is dropped
  unanswered, and the first valid one fixes the port. The key is the server's, new at
  every registration. What goes out is bounded per client by a token bucket at the
  sensor's rate over ``every`` (bursts of ``DATAGRAM_BURST_S``), whatever the sensor
  delivers at once. So a sender without the token makes the server send nothing by
  UDP, to anyone.
- Accept errors (out of file descriptors or memory) shed the oldest connection still
  waiting for HELLO and pause accepting briefly; the channel's thread is supervised:
  an exception is logged and the loop goes on; if the thread ends anyway, a watchdog
  on the event loop starts a new one.

The sensor's thread only ever takes one client's lock, held by others for a
non-blocking ``send`` at most, and only for clients that have said HELLO.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import logging
import math
import resource
import secrets
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from telerobot.drivers.base import ForceSample, TelerobotError
from telerobot.protocol import messages as m
from telerobot.protocol.netprio import mark_high_priority
from telerobot.protocol.typed import DatagramsMessage, parse
from telerobot.server.control.arm_guard import arm_sensors
from telerobot.server.control.decision import DecisionServer
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.ratelimit import BURST, MESSAGES_PER_S, TokenBucket
from telerobot.server.realtime.session import Session, error
from telerobot.tuning import prompt_thread

log = logging.getLogger(__name__)

LENGTH = m.LENGTH

# The limits are module constants rather than settings: they protect the server from
# its clients and need no tuning per deployment (settings.py stays for what an
# operator chooses). PriorityChannel takes each as a keyword argument (the tests
# pass small ones).
MAX_QUEUED_FORCES = 200  # 200 ms at 1 kHz: older ones are dropped for newer
MAX_QUEUED_REPLIES = 256  # replies and events waiting for a client: beyond, it is closed
REPLY_PAUSE = 64  # a client's socket is not read while this many replies wait for it
MAX_CONNECTIONS = 32  # sockets open at once (a master-arm bridge needs one)
MAX_PENDING = 8  # of those, still waiting for HELLO
HELLO_TIMEOUT_S = 3.0  # a client says HELLO at once; an idle socket is closed after this
MAX_MESSAGE_BYTES = 1024  # the largest client message, HELLO, is 69 bytes
MAX_INBOX = 64  # messages read from one client and not yet handled on the event loop
MAX_RX_BYTES = 16 * 1024  # bytes read from one client and not yet split into messages
MAX_MESSAGES_PER_S = MESSAGES_PER_S  # as /ws (ratelimit.py); the bridge sends ~130 a second
MAX_BURST = BURST  # at once (a queue of commands after a stall)
ACCEPT_BACKOFF_S = (0.05, 1.0)  # accepting pauses this long after EMFILE & co, doubling
WATCHDOG_S = 1.0  # how often the event loop checks that the channel's thread runs
RESTART_BACKOFF_S = (0.05, 1.0)  # the thread's loop waits this long after an exception
# Forces as UDP datagrams (DATAGRAMS): back to TCP after this long without a datagram
# from the client (it sends one at least every second).
DATAGRAM_TIMEOUT_S = 2.0
MAX_EVERY = 1000  # DATAGRAMS.every: at least one sample a second
MAX_DATAGRAMS_PER_STEP = 64  # read at once; a UDP flood then waits behind the TCP clients
# What one client may be sent as datagrams: the sensor's samples at its ``every``, with
# this much slack for a sensor's jitter, in bursts of this long (a network sensor's
# samples can arrive bunched after a hiccup; older than that, lost beats late).
DATAGRAM_RATE_SLACK = 1.25
DATAGRAM_BURST_S = 0.05
DEFAULT_FORCE_RATE_HZ = 1000.0  # a sensor that does not say its rate (ForceSensor.rate_hz)

# accept() errors that mean "out of resources": shed, pause, try again later.
_OUT_OF_RESOURCES = {errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM}
_ACCEPT = "accept"
_WAKE = "wake"
_DATAGRAM = "datagram"


frame = m.frame


def connection_cap(wanted: int) -> int:
    """``wanted``, but at most a quarter of the process's file-descriptor limit (the
    rest is for the HTTP server, /ws, devices and files)."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft == resource.RLIM_INFINITY:
        return max(1, wanted)
    return max(1, min(wanted, soft // 4))


class Stage(Enum):
    HELLO = "waiting for HELLO"  # only the first message is read
    JOINING = "HELLO being answered"  # nothing is read until WELCOME
    OPEN = "open"  # commands are read, forces are written


class Kind(Enum):
    FORCE = 0  # bounded, the oldest dropped for the newest
    STATE = 1  # one slot, the newest wins
    REPLY = 2  # bounded, in order; a client that falls this far behind is closed


@dataclass(eq=False)
class PriorityClient:
    sock: socket.socket
    peer: str
    host: str = ""  # the TCP peer's IP address: the only one datagrams go to
    accepted_at: float = 0.0  # time.monotonic()
    stage: Stage = Stage.HELLO
    # Read, not yet handled: bytes not yet split into messages, then messages.
    rx: bytearray = field(default_factory=bytearray, repr=False)
    inbox: deque[tuple[bytes, float]] = field(default_factory=deque, repr=False)
    bucket: TokenBucket = field(default_factory=lambda: TokenBucket(MAX_MESSAGES_PER_S, MAX_BURST))
    read_blocked: bool = False  # reading waits for the event loop to make room
    notify_pending: bool = False  # a wake-up of the worker is on its way to the loop
    ready: asyncio.Event | None = None  # set when the inbox has something
    # What to send: whole frames; ``head`` is the rest of a frame partly sent.
    replies: deque[bytes] = field(default_factory=deque, repr=False)
    forces: deque[bytes] = field(
        default_factory=lambda: deque(maxlen=MAX_QUEUED_FORCES), repr=False
    )
    state: bytes | None = field(default=None, repr=False)
    head: memoryview | None = field(default=None, repr=False)
    forces_dropped: int = 0
    # Forces as datagrams: the key the server gave this client (DATAGRAMS on TCP; new
    # at every registration), the address its first datagram with that key came from
    # (fixed from then on) and when the last one came (time.monotonic()).
    datagram_key: bytes | None = None
    datagram_addr: Any = None
    datagram_heard: float = -math.inf
    datagram_every: int = 1  # one sample in this many (the client's choice)
    # Datagrams this client may still be sent (the sensor's thread takes, alone).
    datagram_bucket: TokenBucket | None = field(default=None, repr=False)
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)
    events: int = 0  # what the selector watches for this socket (0: not registered)
    session: Session | None = None  # once HELLO has been answered
    worker: asyncio.Task[None] | None = None
    closed: bool = False
    close_reason: str | None = None

    @property
    def queued_forces(self) -> int:
        return len(self.forces)

    def has_tx(self) -> bool:
        return bool(self.head is not None or self.replies or self.forces or self.state)

    def flush(self) -> bool:
        """Send what the socket takes now (caller holds ``lock``); True if all went.
        Replies, then the one newest state, then the forces: a client that reads a
        little slower than the forces come would otherwise never be sent a state (the
        forces' queue never empties), and the state costs the forces one small frame
        at most every state period."""
        while True:
            if self.head is None:
                if self.replies:
                    data = self.replies.popleft()
                elif self.state is not None:
                    data, self.state = self.state, None
                elif self.forces:
                    data = self.forces.popleft()
                else:
                    return True
                self.head = memoryview(data)
            try:
                sent = self.sock.send(self.head)
            except (BlockingIOError, InterruptedError):
                return False
            self.head = self.head[sent:] if sent < len(self.head) else None
            if self.head is not None:
                return False

    def push(self, data: bytes, kind: Kind) -> bool:
        """Queue a frame and send what fits; True if the channel's thread has to look
        at this client (something left to send, or it has just been closed)."""
        with self.lock:
            if self.closed:
                return False
            if kind is Kind.FORCE:
                if len(self.forces) == MAX_QUEUED_FORCES:
                    self.forces_dropped += 1  # the deque drops the oldest
                self.forces.append(data)
            elif kind is Kind.STATE:
                self.state = data
            elif len(self.replies) >= MAX_QUEUED_REPLIES:
                self.closed = True
                self.close_reason = f"{MAX_QUEUED_REPLIES} replies left unread"
                return True
            else:
                self.replies.append(data)
            try:
                return not self.flush()
            except OSError as exc:
                self.closed = True
                self.close_reason = self.close_reason or str(exc)
                return True


class PriorityChannel:
    def __init__(
        self,
        host: str,
        port: int,
        hub: RealtimeHub,
        decision: DecisionServer,
        *,
        max_connections: int = MAX_CONNECTIONS,
        max_pending: int = MAX_PENDING,
        hello_timeout_s: float = HELLO_TIMEOUT_S,
        max_message_bytes: int = MAX_MESSAGE_BYTES,
        max_inbox: int = MAX_INBOX,
        max_messages_per_s: float = MAX_MESSAGES_PER_S,
        max_burst: int = MAX_BURST,
        watchdog_s: float = WATCHDOG_S,
    ) -> None:
        self.hub = hub
        self.decision = decision
        self.max_connections = connection_cap(max_connections)
        self.max_pending = max(1, min(max_pending, self.max_connections))
        self.hello_timeout_s = hello_timeout_s
        self.max_message_bytes = min(max_message_bytes, MAX_RX_BYTES - LENGTH.size)
        self.max_inbox = max(1, max_inbox)
        self.max_messages_per_s = max_messages_per_s
        self.max_burst = max(1, max_burst)
        self.watchdog_s = watchdog_s
        self._listener = socket.create_server(
            (host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET
        )
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self._udp = self._datagram_socket(host)
        # DATAGRAMS keys → their client (at most one key per client, so as bounded as
        # the connections).
        self._datagram_keys: dict[bytes, PriorityClient] = {}
        # Every open connection, oldest first (the thread adds and removes; others
        # only take a copy with ``list``).
        self.clients: dict[PriorityClient, None] = {}
        # Those that said HELLO: the only ones the sensor's thread writes to.
        self._subscribers: tuple[PriorityClient, ...] = ()
        self._subscribers_lock = threading.Lock()  # between writers; the sensor never takes it
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._stop = threading.Event()
        self._thread = self._new_thread()
        self._watchdog: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._unsubscribe: list[Callable[[], None]] = []
        self._accept_paused_until: float | None = None
        self._accept_backoff_s = ACCEPT_BACKOFF_S[0]
        self._logged_at: dict[str, float] = {}
        # Counters (what the limits turned away; GET /api/v1/force/channel may show them).
        self.samples_sent = 0
        self.refused = 0  # connections closed at once: every slot taken
        self.shed = 0  # connections waiting for HELLO closed for newer ones
        self.hello_timeouts = 0
        self.rate_limited = 0
        self.oversized = 0
        self.accept_errors = 0
        self.restarts = 0  # the thread's loop after an exception, or a new thread
        self.datagrams_sent = 0  # force samples sent as UDP datagrams
        # UDP datagrams refused: no registered key, or not from the key's client's IP
        # address (a forged source) or its first port.
        self.datagrams_refused = 0
        self.datagrams_over_rate = 0  # samples not sent: past a client's rate (bucket)

    def stats(self) -> dict[str, int]:
        return {
            "connections": len(self.clients),
            "refused": self.refused,
            "shed": self.shed,
            "hello_timeouts": self.hello_timeouts,
            "rate_limited": self.rate_limited,
            "oversized": self.oversized,
            "accept_errors": self.accept_errors,
            "restarts": self.restarts,
            "datagrams_sent": self.datagrams_sent,
            "datagrams_refused": self.datagrams_refused,
            "datagrams_over_rate": self.datagrams_over_rate,
        }

    def _datagram_socket(self, host: str) -> socket.socket | None:
        """A UDP socket on the channel's port number, for forces as datagrams; None
        (and DATAGRAMS refused) if that port is taken for UDP."""
        udp = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
        try:
            udp.bind((host, self.port))
        except OSError as exc:
            udp.close()
            log.warning("no UDP port %d for forces as datagrams (%s): TCP only", self.port, exc)
            return None
        udp.setblocking(False)
        mark_high_priority(udp)
        return udp

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._selector.register(self._listener, selectors.EVENT_READ, _ACCEPT)
        self._selector.register(self._wake_r, selectors.EVENT_READ, _WAKE)
        if self._udp is not None:
            self._selector.register(self._udp, selectors.EVENT_READ, _DATAGRAM)
        # Every arm's sensor, each FORCE naming its arm.
        for index, sensor in arm_sensors(self.decision.arms):
            # First: the other subscribers wake the event loop (call_soon_threadsafe),
            # whose thread then takes the GIL from this one, and under video a loop
            # thread put off the CPU while holding it made the datagram wait with it
            # (bench.force_under_video: p99 1.3 → 0.6 ms under video, 0.35 → 0.15 without).
            self._unsubscribe.append(
                sensor.subscribe(functools.partial(self._on_force, arm=index), first=True)
            )
        self._thread.start()
        self._watchdog = self._loop.create_task(self._watch(), name="priority-watchdog")

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._stop.set()
        self._wake()
        if self._watchdog is not None:
            self._watchdog.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._watchdog
        await asyncio.to_thread(self._thread.join, 2)
        for client in list(self.clients):
            self.clients.pop(client, None)
            with client.lock:
                client.closed = True
            _close_socket(client.sock)
            await self._leave(client)
        self._subscribers = ()
        self._selector.close()
        self._listener.close()
        if self._udp is not None:
            self._udp.close()
        self._wake_r.close()
        self._wake_w.close()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    def _new_thread(self) -> threading.Thread:
        return threading.Thread(target=self._run, name="priority-channel", daemon=True)

    async def _watch(self) -> None:
        """Start a new thread if the channel's has ended (the loop inside survives
        exceptions; this is for whatever ends a thread anyway)."""
        while not self._stop.is_set():
            await asyncio.sleep(self.watchdog_s)
            if not self._thread.is_alive() and not self._stop.is_set():
                self.restarts += 1
                log.error("the priority channel's thread has ended: starting a new one")
                self._thread = self._new_thread()
                self._thread.start()

    # ------------------------------------------------------------ forces (sensor thread)
    def _on_force(self, sample: ForceSample, arm: int = 1) -> None:
        message = m.encode_force([(sample.seq, sample.time, sample.values)], arm)
        data = frame(message)
        look = False
        now = time.monotonic()
        for client in self._subscribers:  # only clients that said HELLO
            if client.closed:
                continue
            self.samples_sent += 1
            addr = client.datagram_addr
            if addr is not None and now - client.datagram_heard < DATAGRAM_TIMEOUT_S:
                if sample.seq % client.datagram_every == 0:
                    bucket = client.datagram_bucket
                    if bucket is not None and bucket.take(now) > 0:
                        self.datagrams_over_rate += 1  # a burst past its rate: lost, not late
                        bucket.tokens += 1  # (not taken: a refused one costs nothing)
                    else:
                        self._send_datagram(client, message, addr)
            else:
                look |= client.push(data, Kind.FORCE)
        if look:
            self._wake()  # the channel's thread sends the rest when the socket drains

    def _send_datagram(self, client: PriorityClient, message: bytes, addr: Any) -> None:
        assert self._udp is not None  # (an address is only learnt through it)
        try:
            self._udp.sendto(message, addr)
            self.datagrams_sent += 1
        except (BlockingIOError, InterruptedError):
            client.forces_dropped += 1  # the socket's buffer is full: this one is lost
        except OSError as exc:  # (unreachable, …): TCP until the client says otherwise
            client.datagram_addr = None
            self._log_limited("datagram", "forces to %s as datagrams failed: %s", addr, exc)

    # ------------------------------------------------------------ the channel's thread
    def _run(self) -> None:
        prompt_thread()  # it flushes what the sensor's thread could not send at once
        backoff = RESTART_BACKOFF_S[0]
        while not self._stop.is_set():
            try:
                self._step()
                backoff = RESTART_BACKOFF_S[0]
            except Exception:
                self.restarts += 1
                log.exception("the priority channel's loop failed: going on in %.2f s", backoff)
                self._stop.wait(backoff)
                backoff = min(2 * backoff, RESTART_BACKOFF_S[1])

    def _step(self) -> None:
        timeout = self._maintain(time.monotonic())
        for key, events in self._selector.select(timeout):
            if key.data == _ACCEPT:
                self._accept()
            elif key.data == _WAKE:
                with contextlib.suppress(OSError):
                    self._wake_r.recv(4096)
            elif key.data == _DATAGRAM:
                self._read_datagrams()
            else:
                client: PriorityClient = key.data
                try:
                    if events & selectors.EVENT_READ and not client.closed:
                        self._read(client)
                    if events & selectors.EVENT_WRITE and not client.closed:
                        with client.lock:
                            client.flush()
                except Exception as exc:  # one client's trouble ends that client only
                    if not isinstance(exc, OSError):
                        log.exception("priority client %s failed", client.peer)
                    client.closed = True
                    client.close_reason = client.close_reason or str(exc)

    def _maintain(self, now: float) -> float:
        """Close what is closed or overdue, read on from held-back bytes, and ask the
        selector for what each socket needs; returns how long select may wait."""
        timeout = 0.5
        if self._accept_paused_until is not None:
            if now >= self._accept_paused_until:
                self._accept_paused_until = None
                with contextlib.suppress(KeyError):  # (already, after a failed step)
                    self._selector.register(self._listener, selectors.EVENT_READ, _ACCEPT)
            else:
                timeout = min(timeout, self._accept_paused_until - now)
        for client in list(self.clients):
            if not client.closed and client.stage is Stage.HELLO:
                left = client.accepted_at + self.hello_timeout_s - now
                if left <= 0:
                    self.hello_timeouts += 1
                    self._refuse(client, "malformed", f"no HELLO within {self.hello_timeout_s:g} s")
                else:
                    timeout = min(timeout, left)
            elif (
                not client.closed
                and client.stage is Stage.OPEN
                and client.rx
                and len(client.inbox) < self.max_inbox
                and len(client.replies) < REPLY_PAUSE
            ):
                self._parse(client, now)  # messages held back while the inbox was full
            if client.closed:
                self._forget(client)
                continue
            want = selectors.EVENT_READ if self._wants_read(client) else 0
            if client.has_tx():
                want |= selectors.EVENT_WRITE
            self._watch_socket(client, want)
        return max(timeout, 0.0)

    def _read_datagrams(self) -> None:
        """DATAGRAMS from the clients' UDP sockets: where their forces go from now on.
        Anything else is dropped unanswered (no reply: a forged source address gets
        nothing back), and so is a datagram with a client's key from anywhere but that
        client's TCP address (the IP; the port its first one came from): UDP's source
        can be forged, and the key crosses the network in clear."""
        assert self._udp is not None
        for _ in range(MAX_DATAGRAMS_PER_STEP):
            try:
                data, addr = self._udp.recvfrom(64)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # (an ICMP error reported on the socket)
            client = None
            if len(data) == m.DATAGRAMS.size and data[0] == m.DATAGRAMS.type_id:
                _, _, key, every = m.DATAGRAMS.struct.unpack(data)
                client = self._datagram_keys.get(key) if 1 <= every <= MAX_EVERY else None
            if client is None or client.closed or addr[0] != client.host:
                self.datagrams_refused += 1
                continue
            with client.lock:  # (against a new registration on the event loop)
                if client.datagram_key != key or client.datagram_addr not in (None, addr):
                    self.datagrams_refused += 1
                    continue
                if client.datagram_addr is None:
                    log.info("priority client %s: forces as datagrams to %s", client.peer, addr)
                client.datagram_addr = addr
                client.datagram_every = every
                client.datagram_bucket = self._datagram_bucket(every, client.datagram_bucket)
                client.datagram_heard = time.monotonic()

    def _datagram_bucket(self, every: int, bucket: TokenBucket | None) -> TokenBucket:
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

    def register_datagrams(self, client: PriorityClient, message: bytes) -> bytes:
        """DATAGRAMS on the client's TCP socket (on the event loop): the reply, with a
        new key (the old one, and the address learnt with it, no longer count)."""
        asked = parse(message)
        if not isinstance(asked, DatagramsMessage):  # (``_serve`` sends only those here)
            raise m.MalformedMessage(f"{asked.SPEC.name} is not DATAGRAMS")
        seq, every = asked.seq, asked.every
        if not 1 <= every <= MAX_EVERY:
            return error(seq, "invalid_command", f"every must be 1 to {MAX_EVERY}")
        if self._udp is None:
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
            self._datagram_keys.pop(old, None)
        self._datagram_keys[key] = client
        return DatagramsMessage(seq=seq, key=key, every=every).encode()

    def _forget_datagrams(self, client: PriorityClient) -> None:
        if client.datagram_key is not None:
            self._datagram_keys.pop(client.datagram_key, None)
        client.datagram_addr = None

    def _wants_read(self, client: PriorityClient) -> bool:
        if client.stage is Stage.HELLO:
            return True
        if client.stage is Stage.JOINING:
            return False
        if len(client.replies) >= REPLY_PAUSE:
            return False  # until the socket drains (this thread sends, and looks again)
        if len(client.inbox) < self.max_inbox and len(client.rx) < MAX_RX_BYTES:
            return True
        client.read_blocked = True  # as in _parse: the flag, then the check
        if len(client.inbox) >= self.max_inbox:
            return False  # the worker wakes this thread when it has made room
        client.read_blocked = False
        return len(client.rx) < MAX_RX_BYTES

    def _watch_socket(self, client: PriorityClient, want: int) -> None:
        if want == client.events:
            return
        if client.events == 0:
            self._selector.register(client.sock, want, client)
        elif want == 0:
            self._selector.unregister(client.sock)
        else:
            self._selector.modify(client.sock, want, client)
        client.events = want

    def _accept_socket(self) -> tuple[socket.socket, Any]:
        return self._listener.accept()

    def _accept(self) -> None:
        for _ in range(16):  # a few at a time, then the others get a turn
            try:
                sock, address = self._accept_socket()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.accept_errors += 1
                if exc.errno not in _OUT_OF_RESOURCES:
                    continue  # that one connection failed (ECONNABORTED, …)
                self._pause_accepting(exc)
                return
            self._accept_backoff_s = ACCEPT_BACKOFF_S[0]
            self._admit(sock, f"{address[0]}:{address[1]}", address[0])

    def _pause_accepting(self, exc: OSError) -> None:
        """Out of file descriptors (or memory): free one by shedding the oldest client
        still waiting for HELLO, and stop accepting for a moment (the listener would
        otherwise stay readable and spin)."""
        self._log_limited(
            "accept", "the priority channel cannot accept (%s): pausing %.2f s",
            exc.strerror, self._accept_backoff_s,
        )  # fmt: skip
        pending = [c for c in self.clients if c.stage is Stage.HELLO and not c.closed]
        if pending:
            self.shed += 1
            self._refuse(pending[0], "limit_exceeded", "the server is short of connections")
            self._forget(pending[0])
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(self._listener)
        self._accept_paused_until = time.monotonic() + self._accept_backoff_s
        self._accept_backoff_s = min(2 * self._accept_backoff_s, ACCEPT_BACKOFF_S[1])

    def _admit(self, sock: socket.socket, peer: str, host: str = "") -> None:
        try:
            sock.setblocking(False)
            mark_high_priority(sock)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            _close_socket(sock)
            return
        open_ = [c for c in self.clients if not c.closed]
        pending = [c for c in open_ if c.stage is Stage.HELLO]
        if pending and (len(pending) >= self.max_pending or len(open_) >= self.max_connections):
            self.shed += 1
            self._refuse(
                pending[0],
                "limit_exceeded",
                f"too many connections waiting for HELLO ({self.max_pending}): say HELLO at once",
            )
            self._forget(pending[0])
            open_.remove(pending[0])
        if len(open_) >= self.max_connections:
            self.refused += 1
            self._log_limited("refused", "priority channel full: refused %s", peer)
            text = f"the priority channel has {self.max_connections} connections: try again later"
            _close_socket(sock, frame(error(0, "limit_exceeded", text)))
            return
        now = time.monotonic()
        client = PriorityClient(
            sock,
            peer,
            host=host,
            accepted_at=now,
            bucket=TokenBucket(self.max_messages_per_s, self.max_burst),
        )
        self.clients[client] = None
        self._watch_socket(client, selectors.EVENT_READ)

    def _read(self, client: PriorityClient) -> None:
        rx = client.rx
        if client.stage is Stage.HELLO:
            # Exactly up to the end of the first message: nothing after it is read
            # before it has been answered.
            if len(rx) < LENGTH.size:
                want = LENGTH.size - len(rx)
            else:
                want = LENGTH.size + LENGTH.unpack_from(rx)[0] - len(rx)
        elif client.stage is Stage.OPEN:
            want = min(65536, MAX_RX_BYTES - len(rx))
        else:
            return
        if want <= 0:
            return
        try:
            data = client.sock.recv(want)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            client.closed = True
            return
        rx += data
        now = time.monotonic()
        if client.stage is Stage.OPEN:
            self._parse(client, now)
            return
        if len(rx) < LENGTH.size:
            return
        (size,) = LENGTH.unpack_from(rx)
        if size > self.max_message_bytes:
            self.oversized += 1
            self._refuse(client, "malformed", f"a first message of {size} bytes: HELLO is 69")
            return
        if len(rx) == LENGTH.size + size:
            hello = bytes(rx[LENGTH.size :])
            rx.clear()
            client.stage = Stage.JOINING
            self._call_soon(self._hello, client, hello)

    def _parse(self, client: PriorityClient, now: float) -> None:
        """Split what was read into messages for the inbox, while it has room, each
        counted against the rate limit before anything is done with it."""
        rx, inbox = client.rx, client.inbox
        received = self.hub.clock.now()
        added = False
        while len(rx) >= LENGTH.size:
            (size,) = LENGTH.unpack_from(rx)
            if size > self.max_message_bytes:
                self.oversized += 1
                self._refuse(
                    client,
                    "malformed",
                    f"a message of {size} bytes: at most {self.max_message_bytes}",
                )
                return
            if len(rx) < LENGTH.size + size or len(client.replies) >= REPLY_PAUSE:
                break  # (replies waiting: this thread looks again when the socket drains)
            if len(inbox) >= self.max_inbox:
                # Held back. The flag first, then the check: either the worker sees
                # the flag when it makes room (and wakes this thread), or this sees
                # the room.
                client.read_blocked = True
                if len(inbox) >= self.max_inbox:
                    break
                client.read_blocked = False
            if client.bucket.take(now) > 0:  # over its rate: no waiting here, closed
                self.rate_limited += 1
                self._refuse(
                    client,
                    "limit_exceeded",
                    f"more than {self.max_messages_per_s:g} messages a second"
                    f" (bursts of {self.max_burst}): closing",
                )
                return
            inbox.append((bytes(rx[LENGTH.size : LENGTH.size + size]), received))
            del rx[: LENGTH.size + size]
            added = True
        if added and not client.notify_pending:
            client.notify_pending = True
            self._call_soon(self._notify, client)

    def _refuse(self, client: PriorityClient, code: str, text: str) -> None:
        """Tell the client why (if it reads), and close it."""
        self._log_limited(code, "priority client %s closed: %s", client.peer, text)
        client.push(frame(error(0, code, text)), Kind.REPLY)
        client.closed = True
        client.close_reason = client.close_reason or text

    def _forget(self, client: PriorityClient) -> None:
        self.clients.pop(client, None)
        client.closed = True
        self._drop_subscriber(client)
        self._forget_datagrams(client)
        if client.events:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(client.sock)
            client.events = 0
        with client.lock:  # no send of the sensor's is under way once this is taken
            client.closed = True
        _close_socket(client.sock)  # outside the lock: the sensor's thread never waits on it
        if client.stage is not Stage.HELLO and self._loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop has closed
                asyncio.run_coroutine_threadsafe(self._leave(client), self._loop)

    def _call_soon(self, callback: Callable[..., None], *args: Any) -> None:
        assert self._loop is not None
        with contextlib.suppress(RuntimeError):  # the loop has closed
            self._loop.call_soon_threadsafe(callback, *args)

    def _drop_subscriber(self, client: PriorityClient) -> None:
        with self._subscribers_lock:
            if client in self._subscribers:
                self._subscribers = tuple(c for c in self._subscribers if c is not client)

    def _log_limited(self, key: str, fmt: str, *args: object) -> None:
        """Log a refusal at most once a second per kind (a flood must not flood the log)."""
        now = time.monotonic()
        if now - self._logged_at.get(key, -1e9) >= 1.0:
            self._logged_at[key] = now
            log.warning(fmt, *args)

    # ------------------------------------------------------------ the event loop
    def _send_soon(self, client: PriorityClient, message: bytes) -> None:
        kind = Kind.STATE if message[:1] == bytes([m.STATE.type_id]) else Kind.REPLY
        if client.push(frame(message), kind):
            self._wake()

    def _close_soon(self, client: PriorityClient, code: str, text: str) -> None:
        self._refuse(client, code, text)
        self._wake()

    def _notify(self, client: PriorityClient) -> None:
        client.notify_pending = False
        if client.ready is not None:
            client.ready.set()

    def _hello(self, client: PriorityClient, message: bytes) -> None:
        """The first message, on the event loop: WELCOME, or ERROR and close."""
        if client.closed:
            return
        try:
            self._welcome(client, message)
        except Exception as exc:  # never leave a client half-joined and unread
            log.exception("priority client %s: HELLO could not be answered", client.peer)
            self._close_soon(client, "telerobot_error", f"the server failed: {exc}")

    def _welcome(self, client: PriorityClient, message: bytes) -> None:
        async def send(data: bytes) -> None:
            self._send_soon(client, data)

        async def superseded() -> None:  # its session resumed elsewhere: closed now
            self._close_soon(client, "not_allowed", "this session resumed on a new connection")

        try:
            session = Session.open(
                message,
                decision=self.decision,
                hub=self.hub,
                peer=f"priority {client.peer}",
                send=send,
                every_force_sample=True,
                direct_forces=True,  # written by the sensor's thread, above
                source="priority",
                address=client.host,
                close_transport=superseded,
            )
        except (m.MalformedMessage, KeyError) as exc:
            self._close_soon(client, "malformed", str(exc))
            return
        except TelerobotError as exc:
            self._close_soon(client, exc.code, str(exc))
            return
        client.session = session
        client.ready = asyncio.Event()
        # WELCOME first on the wire: before the state (hub) and the forces (sensor).
        for welcome in session.welcome:  # WELCOME, then an ARM for each arm
            self._send_soon(client, welcome)
        session.attach()
        client.stage = Stage.OPEN
        with self._subscribers_lock:  # from now on the sensor's thread sends it forces
            self._subscribers = (*self._subscribers, client)
        client.worker = asyncio.create_task(self._serve(client), name=f"priority-{session.id}")
        self._wake()  # read on: what came after HELLO waits in the socket

    async def _serve(self, client: PriorityClient) -> None:
        """Every command in order, like /ws; the loop gets a turn between two."""
        assert client.ready is not None and client.session is not None
        session, inbox = client.session, client.inbox
        try:
            while not client.closed:
                if not inbox:
                    client.ready.clear()
                    if not inbox:
                        await client.ready.wait()
                    continue
                message, received = inbox.popleft()
                if client.read_blocked and len(inbox) <= self.max_inbox // 2:
                    client.read_blocked = False
                    self._wake()  # room again: read on
                if (
                    message[:1] == bytes((m.DATAGRAMS.type_id,))
                    and len(message) == m.DATAGRAMS.size
                    and not session.superseded
                ):
                    self.decision.seen(session.client.id)  # a message like any other
                    self._send_soon(client, self.register_datagrams(client, message))
                    continue
                await session.receive(message, received)
                await asyncio.sleep(0)
        except asyncio.CancelledError:
            raise
        except Exception as exc:
            log.exception("priority client %s: a message could not be handled", client.peer)
            self._close_soon(client, "telerobot_error", f"the server failed: {exc}")

    async def _leave(self, client: PriorityClient) -> None:
        client.closed = True
        self._drop_subscriber(client)
        self._forget_datagrams(client)
        if client.worker is not None and client.worker is not asyncio.current_task():
            client.worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await client.worker
        if client.session is not None:
            session, client.session = client.session, None
            await session.close()


def _close_socket(sock: socket.socket, last: bytes = b"") -> None:
    """Close without a reset where we can: send ``last`` (best effort), read and drop
    what the peer already sent (unread data makes close() send RST, which can cost
    the peer the ERROR), then shut down and close."""
    with contextlib.suppress(OSError):
        if last:
            sock.send(last)
        for _ in range(16):  # at most 1 MiB from a flooding client
            if not sock.recv(65536):
                break
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()
