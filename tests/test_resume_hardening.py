"""Session resume on /ws, hardened: a connection superseded by a
resume is closed at once (the server lets its socket go, whether its peer answers or
not), a resume key works once (the next comes in the resume's WELCOME), resumes are
limited per address, and connections still closing count against the client cap.

Real servers and sockets; the server's own sockets are counted with psutil. Clients
come from distinct loopback addresses (127.0.0.x) where a test must not spend another
test's per-address budget."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import time
from collections.abc import Iterator
from typing import Any
from urllib.parse import urlsplit

import httpx
import psutil
import pytest
import websockets

from harness.wsclient import RealtimeClient
from telerobot.protocol import messages as m
from telerobot.server.realtime.hub import RESUME_BURST
from tests.support import until_async
from tests.support.servers import serving

RESUMABLE = m.HelloFlags.RESUMABLE
RESUME = m.HelloFlags.RESUME | m.HelloFlags.RESUMABLE


@pytest.fixture(scope="module")
def base() -> Iterator[str]:
    with serving() as url:
        yield url


def ws_url(base: str) -> str:
    return base.replace("http://", "ws://") + "ws"


def server_process(base: str) -> psutil.Process:
    """The `telerobot serve` under test: the child of this process listening on its port."""
    port = urlsplit(base).port
    for proc in psutil.Process().children(recursive=True):
        with contextlib.suppress(psutil.Error):
            if any(
                c.status == psutil.CONN_LISTEN and c.laddr.port == port
                for c in proc.net_connections("tcp")
            ):
                return proc
    raise AssertionError(f"no child process listens on {port}")


def held_from(proc: psutil.Process, address: str) -> int:
    """Sockets the server holds (has a file descriptor for) to peers at ``address``."""
    return sum(1 for c in proc.net_connections("tcp") if c.raddr and c.raddr.ip == address)


async def open_from(base: str, address: str) -> Any:
    """A client connection from ``address``, which reads all it is sent (with a bounded
    queue, a client that did not read for a while would not see the server's close)."""
    return await websockets.connect(
        ws_url(base), max_size=None, max_queue=None, compression=None, local_addr=(address, 0)
    )


async def resume_from(base: str, address: str, key: str) -> RealtimeClient:
    return await RealtimeClient.resume(await open_from(base, address), key)


async def refusal(ws: Any) -> str:
    """The ERROR the server answers a HELLO with (then it closes)."""
    with pytest.raises(RuntimeError) as refused:
        await RealtimeClient.expect_message(RealtimeClient(ws), m.WELCOME)
    return str(refused.value)


async def test_superseded_connections_are_closed_at_once_and_resumes_do_not_pile_up(
    base: str,
) -> None:
    """bench.abuse's resume_pileup attack: one observer's key resumed again and again,
    every connection kept open by the client. Before, each stayed open on the server
    (700 resumes held 476 sockets); now the server holds the newest only, and each one
    left behind was closed by the server with 4001 and the reason."""
    proc = server_process(base)
    address = "127.0.0.2"
    client = await RealtimeClient.hello(await open_from(base, address), "", RESUMABLE)
    kept = [client]
    for _ in range(RESUME_BURST - 1):  # all within the per-address budget
        client = await resume_from(base, address, client.resume_key)
        kept.append(client)
    try:
        await until_async(
            lambda: held_from(proc, address) <= 1,
            timeout=20,
            what=lambda: f"the server holds {held_from(proc, address)} sockets from {address}",
        )
        for old in kept[:-1]:  # each was closed by the server, saying why
            await asyncio.wait_for(old.ws.wait_closed(), 10)
            assert old.ws.close_code == 4001, old.ws.close_code
            assert "resumed on a new connection" in (old.ws.close_reason or "")
        # The newest is the session: it is served.
        await client.ws.send(m.encode(m.PING, 1, 0.0))
        await client.expect(m.PONG)
    finally:
        for c in kept:
            await c.ws.close()


async def test_a_peer_that_never_answers_the_close_is_let_go_too(base: str) -> None:
    """A superseded peer that reads nothing more (a stalled link, or an attacker) cannot
    hold its socket on the server by not answering the close."""
    proc = server_process(base)
    address = "127.0.0.3"
    port = urlsplit(base).port or 0
    with socket.socket() as raw:
        # A WebSocket handshake and a HELLO by hand; after its WELCOME this socket reads
        # and answers nothing.
        raw.bind((address, 0))
        raw.settimeout(10)
        raw.connect(("127.0.0.1", port))
        raw.sendall(
            f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            "Sec-WebSocket-Version: 13\r\n\r\n".encode()
        )
        head, _, rest = read_until(raw, b"", b"\r\n\r\n").partition(b"\r\n\r\n")
        assert b" 101 " in head, head
        raw.sendall(masked_binary_frame(m.encode(m.HELLO, m.PROTOCOL_VERSION, RESUMABLE, b"")))
        welcome = first_frame(raw, rest)
        assert welcome[0] == m.WELCOME.type_id
        key = welcome[m.WELCOME.size :].decode().split(" ")[1]
        resumed = await resume_from(base, "127.0.0.4", key)
        try:
            await until_async(
                lambda: held_from(proc, address) == 0,
                timeout=20,
                what=lambda: f"the server holds {held_from(proc, address)} sockets from {address}",
            )
        finally:
            await resumed.close()


async def test_a_priority_channel_connection_superseded_by_a_resume_is_closed_too(
    base: str,
) -> None:
    """The same session logic under the priority channel's framing: its connection is
    closed, saying why, when the session resumes on /ws."""
    proc = server_process(base)
    address = "127.0.0.9"
    async with httpx.AsyncClient(base_url=base, timeout=10) as http:
        port = (await http.get("api/v1/force/channel")).json()["port"]
    with socket.socket() as tcp:
        tcp.bind((address, 0))
        tcp.settimeout(10)
        tcp.connect(("127.0.0.1", port))
        tcp.sendall(m.frame(m.encode(m.HELLO, m.PROTOCOL_VERSION, RESUMABLE, b"")))
        messages = FramedReader(tcp)
        welcome = messages.next()
        assert welcome[0] == m.WELCOME.type_id
        key = welcome[m.WELCOME.size :].decode().split(" ")[1]
        resumed = await resume_from(base, "127.0.0.10", key)
        try:
            refusal = messages.until(m.ERROR.type_id)
            assert b"this session resumed on a new connection" in refusal
            assert messages.closed(), "the server kept the connection open"
            await until_async(lambda: held_from(proc, address) == 0, timeout=10)
        finally:
            await resumed.close()


class FramedReader:
    """Length-framed messages off a priority-channel socket (blocking)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock, self.rx = sock, b""

    def next(self) -> bytes:
        while len(self.rx) < 2 or len(self.rx) < 2 + m.LENGTH.unpack_from(self.rx)[0]:
            chunk = self.sock.recv(65536)
            assert chunk, "the server closed the connection"
            self.rx += chunk
        (size,) = m.LENGTH.unpack_from(self.rx)
        message, self.rx = self.rx[2 : 2 + size], self.rx[2 + size :]
        return message

    def until(self, type_id: int, timeout: float = 10.0) -> bytes:
        deadline = time.monotonic() + timeout
        while (message := self.next())[0] != type_id:
            assert time.monotonic() < deadline, f"no message 0x{type_id:02x} in {timeout:g} s"
        return message

    def closed(self) -> bool:
        """True once the server has closed its side (EOF within the socket's timeout)."""
        try:
            while self.sock.recv(65536):
                pass
        except TimeoutError:
            return False
        return True


def read_until(sock: socket.socket, data: bytes, marker: bytes) -> bytes:
    while marker not in data:
        chunk = sock.recv(4096)
        assert chunk, "the server closed the connection"
        data += chunk
    return data


def first_frame(sock: socket.socket, data: bytes) -> bytes:
    """The payload of the first (unmasked, short) frame the server sent."""
    while len(data) < 2 or len(data) < 2 + (data[1] & 0x7F):
        chunk = sock.recv(4096)
        assert chunk, "the server closed the connection"
        data += chunk
    assert data[1] & 0x7F < 126, "a WELCOME is short"
    return data[2 : 2 + (data[1] & 0x7F)]


def masked_binary_frame(payload: bytes) -> bytes:
    assert len(payload) < 126
    mask = b"\x01\x02\x03\x04"
    body = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
    return struct.pack("!BB", 0x82, 0x80 | len(payload)) + mask + body


async def test_a_resume_key_works_once_and_the_next_comes_in_the_welcome(base: str) -> None:
    """Whoever saw a key on the way cannot use it after its owner did: the key is spent
    by the resume, which gets a new one (and the same client id)."""
    address = "127.0.0.5"
    client = await RealtimeClient.hello(await open_from(base, address), "", RESUMABLE)
    spent = client.resume_key
    resumed = await resume_from(base, address, spent)
    try:
        assert resumed.client_id == client.client_id
        assert resumed.resume_key and resumed.resume_key != spent
        thief = await open_from(base, "127.0.0.6")
        await thief.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, RESUME, spent.encode()))
        assert "no session to resume" in await refusal(thief)
        # The new key resumes (and is spent in turn).
        again = await resume_from(base, address, resumed.resume_key)
        assert again.client_id == client.client_id and again.resume_key != resumed.resume_key
        await again.close()
    finally:
        await resumed.close()
        await client.close()


async def test_resumes_are_limited_per_address_with_the_reason(base: str) -> None:
    """Resuming in a loop from one address is refused past its budget (ERROR saying
    why, before the key is looked at); the session itself goes on, and another address
    resumes it."""
    address = "127.0.0.7"
    client = await RealtimeClient.hello(await open_from(base, address), "", RESUMABLE)
    key, sockets, resumed, why = client.resume_key, [client.ws], 0, ""
    try:
        for _ in range(6 * RESUME_BURST):  # it refills at 2/s: refused well before this
            ws = await open_from(base, address)
            sockets.append(ws)
            await ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, RESUME, key.encode()))
            try:
                _, _, text = await RealtimeClient(ws).expect_message(m.WELCOME)
            except RuntimeError as exc:
                why = str(exc)
                break
            key = text.split(" ")[1]
            resumed += 1
        assert "too many resumes from 127.0.0.7" in why, why
        assert resumed >= RESUME_BURST  # the burst went through
        # The session goes on: another address resumes it with its current key.
        other = await resume_from(base, "127.0.0.8", key)
        assert other.client_id == client.client_id
        await other.close()
    finally:
        for ws in sockets:
            await ws.close()


async def test_connections_still_closing_count_against_the_client_cap() -> None:
    """A superseded connection whose socket has not been let go yet is still a
    connection: with a cap of 3, two of them closing and the live one fill it."""
    from telerobot.drivers.base import TelerobotError
    from telerobot.drivers.clock import ManualClock
    from telerobot.server.realtime.hub import RealtimeHub
    from telerobot.server.realtime.session import Session
    from telerobot.server.telemetry.stats import Telemetry
    from tests.support.decision import make

    clock = ManualClock()
    decision, _ = await make(clock)
    decision.clients.max_clients = 3
    hub = RealtimeHub(decision, Telemetry(), clock)
    never = asyncio.Event()

    async def send(_: bytes) -> None:
        pass

    async def stalled_close() -> None:  # its framing has not let it go yet
        await never.wait()

    def open_session(token: str, flags: int) -> Session:
        hello = m.encode(m.HELLO, m.PROTOCOL_VERSION, flags, token.encode())
        return Session.open(
            hello,
            decision=decision,
            hub=hub,
            peer="test",
            send=send,
            address="10.0.0.1",
            close_transport=stalled_close,
        )

    session = open_session("", RESUMABLE)
    session.attach()
    for _ in range(2):
        key = session.client.resume_key
        assert key is not None
        session = open_session(key, RESUME)
        session.attach()
    await asyncio.sleep(0)
    assert hub.open_connections == 3 and len(hub.superseded) == 2
    with pytest.raises(TelerobotError, match="3 connections \\(2 of them closing\\)"):
        open_session("", 0)
    never.set()
    await hub.stop()
