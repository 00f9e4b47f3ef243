"""One connection of the priority channel (priority.py): its state, what waits to be
sent to it (``PriorityClient``: replies, the newest state, forces; sent by whichever
thread queues, the rest by the channel's when the socket drains), and its socket read
into messages under the limits (``FrameReader``, on the channel's thread).

Framing: every message is preceded by its length, u16 little-endian; the first must
be HELLO, and nothing past it is read before it has been answered."""

from __future__ import annotations

import asyncio
import math
import socket
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from telerobot.drivers.clock import Clock
from telerobot.protocol import messages as m
from telerobot.server.realtime.ratelimit import BURST, MESSAGES_PER_S, TokenBucket
from telerobot.server.realtime.session import Session

LENGTH = m.LENGTH

# One connection's limits (priority.py's docstring says what each bounds; the channel
# takes those it passes on to FrameReader as keyword arguments, the tests small ones).
MAX_QUEUED_FORCES = 200  # 200 ms at 1 kHz: older ones are dropped for newer
MAX_QUEUED_REPLIES = 256  # replies and events waiting for a client: beyond, it is closed
REPLY_PAUSE = 64  # a client's socket is not read while this many replies wait for it
MAX_MESSAGE_BYTES = 1024  # the largest client message, HELLO, is 69 bytes
MAX_INBOX = 64  # messages read from one client and not yet handled on the event loop
MAX_RX_BYTES = 16 * 1024  # bytes read from one client and not yet split into messages
MAX_MESSAGES_PER_S = MESSAGES_PER_S  # as /ws (ratelimit.py); the bridge sends ~130 a second
MAX_BURST = BURST  # at once (a queue of commands after a stall)


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


class FrameReader:
    """Reads a client's socket into its inbox, on the channel's thread: exactly HELLO
    first, then messages while the inbox has room, each counted against the rate limit
    before anything is done with it. What breaks a limit goes to ``refuse`` (the
    channel tells the client why and closes it); HELLO, read whole, to ``hello``; and
    ``arrived`` is called once per batch of messages, until the worker has taken it."""

    def __init__(
        self,
        clock: Clock,
        *,
        refuse: Callable[[PriorityClient, str, str], None],
        hello: Callable[[PriorityClient, bytes], None],
        arrived: Callable[[PriorityClient], None],
        max_message_bytes: int = MAX_MESSAGE_BYTES,
        max_inbox: int = MAX_INBOX,
        max_messages_per_s: float = MAX_MESSAGES_PER_S,
        max_burst: int = MAX_BURST,
    ) -> None:
        self.clock = clock
        self._refuse = refuse
        self._hello = hello
        self._arrived = arrived
        self.max_message_bytes = min(max_message_bytes, MAX_RX_BYTES - LENGTH.size)
        self.max_inbox = max(1, max_inbox)
        self.max_messages_per_s = max_messages_per_s
        self.max_burst = max(1, max_burst)
        self.rate_limited = 0
        self.oversized = 0

    def bucket(self) -> TokenBucket:
        """A new client's rate limit."""
        return TokenBucket(self.max_messages_per_s, self.max_burst)

    def read(self, client: PriorityClient) -> None:
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
            self.parse(client, now)
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
            self._hello(client, hello)

    def parse(self, client: PriorityClient, now: float) -> None:
        """Split what was read into messages for the inbox, while it has room, each
        counted against the rate limit before anything is done with it."""
        rx, inbox = client.rx, client.inbox
        received = self.clock.now()
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
            self._arrived(client)

    def held_back(self, client: PriorityClient) -> bool:
        """Messages read and held back while the inbox was full, now with room."""
        return (
            not client.closed
            and client.stage is Stage.OPEN
            and bool(client.rx)
            and len(client.inbox) < self.max_inbox
            and len(client.replies) < REPLY_PAUSE
        )

    def wants_read(self, client: PriorityClient) -> bool:
        if client.stage is Stage.HELLO:
            return True
        if client.stage is Stage.JOINING:
            return False
        if len(client.replies) >= REPLY_PAUSE:
            return False  # until the socket drains (this thread sends, and looks again)
        if len(client.inbox) < self.max_inbox and len(client.rx) < MAX_RX_BYTES:
            return True
        client.read_blocked = True  # as in parse: the flag, then the check
        if len(client.inbox) >= self.max_inbox:
            return False  # the worker wakes this thread when it has made room
        client.read_blocked = False
        return len(client.rx) < MAX_RX_BYTES

    def room_again(self, client: PriorityClient) -> bool:
        """The worker took a message: True if reading was held back and may go on."""
        if client.read_blocked and len(client.inbox) <= self.max_inbox // 2:
            client.read_blocked = False
            return True
        return False
