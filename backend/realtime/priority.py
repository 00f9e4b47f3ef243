"""The priority channel: force samples out and commands in, on a TCP socket of their
own, for the master-arm bridge and any client that must feel forces on time.

Why not /ws: a WebSocket shares the server's event loop with everything else, and a
data channel would share the video's congestion control. Here every force sample is
written from the sensor's own thread the moment it is taken (no hop through the
event loop), and the socket is marked high priority (SO_PRIORITY 6, DSCP EF), so a
DiffServ-aware queue on the way sends it ahead of the video (which the media worker
marks low). Commands take the same path as /ws ones (``ws.handle``: lease, limits,
dead-man), in order, on the event loop.

Framing: every message (layouts in ``messages``) is preceded by its length, u16
little-endian. The first message must be HELLO. Every force sample goes out as one
FORCE message with one sample (seq, sensor time, six values). A client that cannot
keep up loses the oldest queued samples, never the newest (counted per client).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import selectors
import socket
import struct
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from backend.control.decision import DecisionServer
from backend.netprio import mark_high_priority
from backend.realtime import messages as m
from backend.realtime.hub import Connection, RealtimeHub
from backend.realtime.ws import error, handle
from drivers.base import ForceSample, ForceSensor

log = logging.getLogger(__name__)

LENGTH = struct.Struct("<H")
MAX_QUEUED_FORCES = 200  # 200 ms at 1 kHz: older ones are dropped for newer


def frame(message: bytes) -> bytes:
    return LENGTH.pack(len(message)) + message


@dataclass(eq=False)
class PriorityClient:
    sock: socket.socket
    peer: str
    rx: bytearray = field(default_factory=bytearray)
    # What to send: whole frames; ``head`` is the rest of a frame partly sent.
    tx: deque[tuple[bytes, bool]] = field(default_factory=deque)  # (frame, is_force)
    head: memoryview | None = None
    queued_forces: int = 0
    forces_dropped: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    client_id: str | None = None
    conn: Connection | None = None
    inbox: asyncio.Queue[tuple[bytes, float]] | None = None
    worker: asyncio.Task[None] | None = None
    closed: bool = False

    def flush(self) -> bool:
        """Send what the socket takes now (caller holds ``lock``); True if all went."""
        while True:
            if self.head is None:
                if not self.tx:
                    return True
                data, is_force = self.tx.popleft()
                self.queued_forces -= is_force
                self.head = memoryview(data)
            try:
                sent = self.sock.send(self.head)
            except BlockingIOError:
                return False
            self.head = self.head[sent:] if sent < len(self.head) else None
            if self.head is not None:
                return False

    def push(self, data: bytes, is_force: bool) -> bool:
        """Queue a frame and send what fits; True if something is left for later."""
        with self.lock:
            if self.closed:
                return False
            if is_force and self.queued_forces >= MAX_QUEUED_FORCES:
                self._drop_oldest_force()
            self.tx.append((data, is_force))
            self.queued_forces += is_force
            try:
                return not self.flush()
            except OSError:
                self.closed = True
                return False

    def _drop_oldest_force(self) -> None:
        for i, (_, is_force) in enumerate(self.tx):
            if is_force:
                del self.tx[i]
                self.queued_forces -= 1
                self.forces_dropped += 1
                return


class PriorityChannel:
    def __init__(
        self,
        host: str,
        port: int,
        hub: RealtimeHub,
        decision: DecisionServer,
        force: ForceSensor | None,
    ) -> None:
        self.hub = hub
        self.decision = decision
        self.force = force
        self._listener = socket.create_server(
            (host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET
        )
        self._listener.setblocking(False)
        self.port: int = self._listener.getsockname()[1]
        self.clients: set[PriorityClient] = set()
        self._selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="priority-channel", daemon=True)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._unsubscribe: list[Callable[[], None]] = []
        self.samples_sent = 0

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._selector.register(self._listener, selectors.EVENT_READ, "accept")
        self._selector.register(self._wake_r, selectors.EVENT_READ, "wake")
        if self.force is not None:
            self._unsubscribe.append(self.force.subscribe(self._on_force))
        self._thread.start()

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._stop.set()
        self._wake()
        await asyncio.to_thread(self._thread.join, 2)
        for client in list(self.clients):
            await self._leave(client)
        self._listener.close()
        self._wake_r.close()
        self._wake_w.close()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    # ------------------------------------------------------------ forces (sensor thread)
    def _on_force(self, sample: ForceSample) -> None:
        data = frame(m.encode_force([(sample.seq, sample.time, sample.values)]))
        pending = False
        for client in list(self.clients):
            if client.conn is not None and not client.closed:
                pending |= client.push(data, True)
                self.samples_sent += 1
        if pending:
            self._wake()  # the channel's thread sends the rest when the socket drains

    # ------------------------------------------------------------ the channel's thread
    def _run(self) -> None:
        while not self._stop.is_set():
            for key, events in self._selector.select(timeout=0.5):
                if key.data == "accept":
                    self._accept()
                elif key.data == "wake":
                    with contextlib.suppress(BlockingIOError):
                        self._wake_r.recv(4096)
                else:
                    client: PriorityClient = key.data
                    if events & selectors.EVENT_READ:
                        self._read(client)
                    if events & selectors.EVENT_WRITE and not client.closed:
                        with client.lock, contextlib.suppress(OSError):
                            client.flush()
            # Ask to hear when a socket with something left to send can take more.
            for client in list(self.clients):
                if client.closed:
                    self._forget(client)
                    continue
                want = selectors.EVENT_READ | (
                    selectors.EVENT_WRITE if client.tx or client.head else 0
                )
                with contextlib.suppress(KeyError, ValueError):
                    if self._selector.get_key(client.sock).events != want:
                        self._selector.modify(client.sock, want, client)

    def _accept(self) -> None:
        try:
            sock, address = self._listener.accept()
        except BlockingIOError:
            return
        sock.setblocking(False)
        mark_high_priority(sock)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client = PriorityClient(sock, f"{address[0]}:{address[1]}")
        self.clients.add(client)
        self._selector.register(sock, selectors.EVENT_READ, client)

    def _read(self, client: PriorityClient) -> None:
        try:
            data = client.sock.recv(65536)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            client.closed = True
            return
        received = self.hub.clock.now()
        client.rx += data
        while len(client.rx) >= LENGTH.size:
            (size,) = LENGTH.unpack_from(client.rx)
            if len(client.rx) < LENGTH.size + size:
                break
            message = bytes(client.rx[LENGTH.size : LENGTH.size + size])
            del client.rx[: LENGTH.size + size]
            assert self._loop is not None
            self._loop.call_soon_threadsafe(self._dispatch, client, message, received)

    def _forget(self, client: PriorityClient) -> None:
        self.clients.discard(client)
        with contextlib.suppress(KeyError, ValueError):
            self._selector.unregister(client.sock)
        client.sock.close()
        if self._loop is not None and not self._loop.is_closed():
            with contextlib.suppress(RuntimeError):
                asyncio.run_coroutine_threadsafe(self._leave(client), self._loop)

    # ------------------------------------------------------------ the event loop
    def _send_soon(self, client: PriorityClient, message: bytes) -> None:
        if client.push(frame(message), False):
            self._wake()

    def _dispatch(self, client: PriorityClient, message: bytes, received: float) -> None:
        if client.inbox is not None:
            client.inbox.put_nowait((message, received))
            return
        if client.worker is not None:
            return  # HELLO is being handled: nothing else is read before WELCOME
        client.worker = asyncio.create_task(self._serve(client, message))

    async def _serve(self, client: PriorityClient, hello: bytes) -> None:
        """HELLO, then every command in order, like /ws."""
        try:
            msg, fields, _ = m.decode(hello)
            if msg is not m.HELLO:
                raise m.MalformedMessage(f"the first message must be HELLO, got {msg.name}")
        except (m.MalformedMessage, KeyError) as exc:
            self._send_soon(client, error(0, "malformed", str(exc)))
            client.closed = True
            self._wake()
            return
        token = bytes(fields["token"]).rstrip(b"\0").decode("ascii", "replace")
        joined = self.decision.join(f"priority {client.peer}", token or None)

        async def send(data: bytes) -> None:
            self._send_soon(client, data)

        conn = Connection(
            send,
            joined.id,
            operator=joined.role.value == "operator",
            every_force_sample=True,
            direct_forces=True,  # written by the sensor's thread, above
        )
        client.client_id = joined.id
        client.inbox = asyncio.Queue()
        conn.reply(
            m.encode(
                m.WELCOME,
                m.PROTOCOL_VERSION,
                int(conn.operator),
                self.hub.clock.now(),
                text=joined.id,
            )
        )
        self.hub.add(conn)
        client.conn = conn  # from now on the sensor's thread sends it forces
        while not client.closed:
            message, received = await client.inbox.get()
            self.decision.seen(joined.id)
            await handle(message, received, joined.id, conn, self.decision, self.hub)

    async def _leave(self, client: PriorityClient) -> None:
        client.closed = True
        if client.worker is not None and client.worker is not asyncio.current_task():
            client.worker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await client.worker
        if client.conn is not None:
            await self.hub.remove(client.conn)
            client.conn = None
        if client.client_id is not None:
            await self.decision.leave(client.client_id)
            client.client_id = None
