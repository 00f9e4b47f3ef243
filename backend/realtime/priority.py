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

Bounded at the edge (docs/architecture.md, rule 18; the values are the constants below,
in priority_connection.py and priority_datagrams.py):

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

This module is the channel: its thread (accept, read, write), the connections' limits
and their sessions on the event loop. One connection's state, queues and reading are
in priority_connection.py, the force path on the sensor's thread in priority_fanout.py,
forces as datagrams in priority_datagrams.py.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import logging
import resource
import selectors
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from telerobot.drivers.base import TelerobotError
from telerobot.protocol import messages as m
from telerobot.protocol.netprio import mark_high_priority
from telerobot.server.control.decision import DecisionServer
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.priority_connection import (
    MAX_BURST,
    MAX_INBOX,
    MAX_MESSAGE_BYTES,
    MAX_MESSAGES_PER_S,
    FrameReader,
    Kind,
    PriorityClient,
    Stage,
)
from telerobot.server.realtime.priority_datagrams import ForceDatagrams
from telerobot.server.realtime.priority_fanout import ForceFanout
from telerobot.server.realtime.session import Session, error
from telerobot.tuning import prompt_thread

log = logging.getLogger(__name__)

LENGTH = m.LENGTH

# The limits are module constants rather than settings: they protect the server from
# its clients and need no tuning per deployment (settings.py stays for what an
# operator chooses). PriorityChannel takes each as a keyword argument (the tests
# pass small ones), one connection's too (priority_connection.py).
MAX_CONNECTIONS = 32  # sockets open at once (a master-arm bridge needs one)
MAX_PENDING = 8  # of those, still waiting for HELLO
HELLO_TIMEOUT_S = 3.0  # a client says HELLO at once; an idle socket is closed after this
ACCEPT_BACKOFF_S = (0.05, 1.0)  # accepting pauses this long after EMFILE & co, doubling
WATCHDOG_S = 1.0  # how often the event loop checks that the channel's thread runs
RESTART_BACKOFF_S = (0.05, 1.0)  # the thread's loop waits this long after an exception

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
        self.watchdog_s = watchdog_s
        self.reader = FrameReader(
            hub.clock,
            refuse=self._refuse,
            hello=functools.partial(self._call_soon, self._hello),
            arrived=functools.partial(self._call_soon, self._notify),
            max_message_bytes=max_message_bytes,
            max_inbox=max_inbox,
            max_messages_per_s=max_messages_per_s,
            max_burst=max_burst,
        )
        self._listener = socket.create_server(
            (host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET
        )
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self.datagrams = ForceDatagrams(host, self.port, decision, self._log_limited)
        # Every open connection, oldest first (the thread adds and removes; others
        # only take a copy with ``list``).
        self.clients: dict[PriorityClient, None] = {}
        self.fanout = ForceFanout(self.datagrams, self._wake)
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._stop = threading.Event()
        self._thread = self._new_thread()
        self._watchdog: asyncio.Task[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._accept_paused_until: float | None = None
        self._accept_backoff_s = ACCEPT_BACKOFF_S[0]
        self._logged_at: dict[str, float] = {}
        # Counters (what the limits turned away; GET /api/v1/force/channel may show them;
        # the reader's, the datagrams' and the fan-out's with them).
        self.refused = 0  # connections closed at once: every slot taken
        self.shed = 0  # connections waiting for HELLO closed for newer ones
        self.hello_timeouts = 0
        self.accept_errors = 0
        self.restarts = 0  # the thread's loop after an exception, or a new thread

    @property
    def samples_sent(self) -> int:
        return self.fanout.samples_sent

    def stats(self) -> dict[str, int]:
        return {
            "connections": len(self.clients),
            "refused": self.refused,
            "shed": self.shed,
            "hello_timeouts": self.hello_timeouts,
            "rate_limited": self.reader.rate_limited,
            "oversized": self.reader.oversized,
            "accept_errors": self.accept_errors,
            "restarts": self.restarts,
            "datagrams_sent": self.datagrams.sent,
            "datagrams_refused": self.datagrams.refused,
            "datagrams_over_rate": self.datagrams.over_rate,
        }

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._selector.register(self._listener, selectors.EVENT_READ, _ACCEPT)
        self._selector.register(self._wake_r, selectors.EVENT_READ, _WAKE)
        if self.datagrams.sock is not None:
            self._selector.register(self.datagrams.sock, selectors.EVENT_READ, _DATAGRAM)
        self.fanout.subscribe(self.decision.arms)
        self._thread.start()
        self._watchdog = self._loop.create_task(self._watch(), name="priority-watchdog")

    async def stop(self) -> None:
        self.fanout.unsubscribe()
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
        self.fanout.subscribers = ()
        self._selector.close()
        self._listener.close()
        self.datagrams.close()
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
                self.datagrams.read()
            else:
                client: PriorityClient = key.data
                try:
                    if events & selectors.EVENT_READ and not client.closed:
                        self.reader.read(client)
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
            elif self.reader.held_back(client):
                self.reader.parse(client, now)  # messages held back while the inbox was full
            if client.closed:
                self._forget(client)
                continue
            want = selectors.EVENT_READ if self.reader.wants_read(client) else 0
            if client.has_tx():
                want |= selectors.EVENT_WRITE
            self._watch_socket(client, want)
        return max(timeout, 0.0)

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
            bucket=self.reader.bucket(),
        )
        self.clients[client] = None
        self._watch_socket(client, selectors.EVENT_READ)

    def _refuse(self, client: PriorityClient, code: str, text: str) -> None:
        """Tell the client why (if it reads), and close it."""
        self._log_limited(code, "priority client %s closed: %s", client.peer, text)
        client.push(frame(error(0, code, text)), Kind.REPLY)
        client.closed = True
        client.close_reason = client.close_reason or text

    def _forget(self, client: PriorityClient) -> None:
        self.clients.pop(client, None)
        client.closed = True
        self.fanout.drop(client)
        self.datagrams.forget(client)
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
        self.fanout.add(client)  # from now on the sensor's thread sends it forces
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
                if self.reader.room_again(client):
                    self._wake()  # room again: read on
                if (
                    message[:1] == bytes((m.DATAGRAMS.type_id,))
                    and len(message) == m.DATAGRAMS.size
                    and not session.superseded
                ):
                    self.decision.seen(session.client.id)  # a message like any other
                    self._send_soon(client, self.datagrams.register(client, message))
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
        self.fanout.drop(client)
        self.datagrams.forget(client)
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
