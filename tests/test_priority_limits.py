"""The priority channel's limits (docs/architecture.md, rule 18), each hit by a real socket
against a real channel: HELLO in time, floods cut off, queues bounded, connection
caps, accept errors survived, and the channel's thread supervised.

The channel runs in this process on an event loop of its own (a thread), with the
simulated arm behind it and a force sensor the test drives, so the tests can look at
its counters and queues; limits are passed small."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest

from telerobot.protocol import messages as m
from telerobot.server.realtime.priority_connection import (
    MAX_QUEUED_FORCES,
    MAX_QUEUED_REPLIES,
    MAX_RX_BYTES,
    REPLY_PAUSE,
    Kind,
    PriorityClient,
    Stage,
)
from tests.support import TOKEN, until
from tests.support.priority import ChannelServer

T = TypeVar("T")


def framed(*messages: bytes) -> bytes:
    return b"".join(struct.pack("<H", len(x)) + x for x in messages)


def hello(token: str = "") -> bytes:
    return m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, token.encode())


def ping(seq: int) -> bytes:
    return m.encode(m.PING, seq, 0.0)


@pytest.fixture
def serve() -> Iterator[Callable[..., ChannelServer]]:
    servers: list[ChannelServer] = []

    def start(**limits: Any) -> ChannelServer:
        servers.append(ChannelServer(**limits))
        return servers[-1]

    yield start
    for server in servers:
        server.close()


class RawClient:
    """A plain TCP client that notes every message it gets (reading in a thread of
    its own, or not at all until told)."""

    def __init__(self, port: int, *, read: bool = True, rcvbuf: int | None = None) -> None:
        self.sock = socket.socket()
        if rcvbuf is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
        self.sock.connect(("127.0.0.1", port))
        self.port = self.sock.getsockname()[1]
        self.messages: list[tuple[str, dict[str, Any], str]] = []
        self.forces = 0
        self.ended = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        if read:
            self._reader.start()

    def start_reading(self) -> None:
        self._reader.start()

    def send(self, *messages: bytes) -> None:
        self.sock.sendall(framed(*messages))  # one write

    def named(self, name: str) -> list[tuple[str, dict[str, Any], str]]:
        return [x for x in list(self.messages) if x[0] == name]

    def errors(self) -> list[tuple[int, str]]:
        return [(int(f["code"]), text) for _, f, text in self.named("ERROR")]

    def close(self) -> None:
        self.sock.close()

    def _read(self) -> None:
        buf = bytearray()
        try:
            while data := self.sock.recv(65536):
                buf += data
                while len(buf) >= 2:
                    (size,) = struct.unpack_from("<H", buf)
                    if len(buf) < 2 + size:
                        break
                    message = bytes(buf[2 : 2 + size])
                    del buf[: 2 + size]
                    if message[0] == m.FORCE.type_id:
                        self.forces += len(m.decode_force(message))
                    else:
                        msg, fields, text = m.decode(message)
                        self.messages.append((msg.name, fields, text))
        except OSError:
            pass
        finally:
            self.ended.set()


LIMIT_EXCEEDED = m.ERROR_CODES["limit_exceeded"]
MALFORMED = m.ERROR_CODES["malformed"]


def welcomed(port: int, token: str = "") -> RawClient:
    client = RawClient(port)
    client.send(hello(token))
    until(lambda: client.named("WELCOME"))
    return client


# ------------------------------------------------------------------ HELLO


def test_every_message_sent_with_hello_in_one_write_is_answered_in_order(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve(max_inbox=8)  # a small inbox: reading pauses and resumes many times
    client = RawClient(server.port)
    client.send(hello(), *(ping(seq) for seq in range(1, 201)))
    until(lambda: len(client.named("PONG")) == 200)
    assert client.messages[0][0] == "WELCOME"  # first on the wire, before STATE and forces
    assert [int(f["seq"]) for _, f, _ in client.named("PONG")] == list(range(1, 201))
    assert not client.errors()
    client.close()


def test_no_hello_within_the_timeout_is_closed(serve: Callable[..., ChannelServer]) -> None:
    server = serve(hello_timeout_s=0.2)
    silent = RawClient(server.port)
    slow = RawClient(server.port)
    slow.sock.sendall(b"\x45\x00\x01")  # the start of a HELLO that never ends
    assert silent.ended.wait(5) and slow.ended.wait(5)
    for client in (silent, slow):
        assert client.errors() == [(MALFORMED, "no HELLO within 0.2 s")]
    assert server.channel.hello_timeouts == 2
    until(lambda: not server.channel.clients)
    welcomed(server.port).close()  # a client that says HELLO at once is served


def test_a_hello_of_another_protocol_version_is_refused(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve()
    client = RawClient(server.port)
    client.send(m.encode(m.HELLO, 999, 0, TOKEN.encode()))
    assert client.ended.wait(5)
    assert client.errors()[0][0] == MALFORMED and "version 999" in client.errors()[0][1]
    assert not client.named("WELCOME")


def test_a_first_message_too_long_for_hello_is_refused(serve: Callable[..., ChannelServer]) -> None:
    server = serve()
    client = RawClient(server.port)
    client.sock.sendall(struct.pack("<H", 60000) + b"\0" * 100)
    assert client.ended.wait(5)
    assert client.errors()[0][0] == MALFORMED and "60000 bytes" in client.errors()[0][1]
    assert server.channel.reader.oversized == 1


def test_a_message_too_long_after_hello_is_refused(serve: Callable[..., ChannelServer]) -> None:
    server = serve(max_message_bytes=100)
    client = welcomed(server.port)
    client.sock.sendall(struct.pack("<H", 101) + b"\x06" * 101)
    assert client.ended.wait(5)
    assert client.errors() == [(MALFORMED, "a message of 101 bytes: at most 100")]
    assert server.channel.reader.oversized == 1


# ------------------------------------------------------------------ floods


def test_a_flood_of_small_frames_is_cut_off_with_bounded_queues(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve(max_inbox=16, max_messages_per_s=100, max_burst=500)
    channel = server.channel
    high = {"inbox": 0, "rx": 0}
    parse = channel.reader.parse

    def watched(client: PriorityClient, now: float) -> None:
        high["rx"] = max(high["rx"], len(client.rx))
        parse(client, now)
        high["inbox"] = max(high["inbox"], len(client.inbox))

    channel.reader.parse = watched  # type: ignore[method-assign]
    attacker = welcomed(server.port)  # an observer: no token
    flood = b"\x01\x00\x04" * 20_000  # 3-byte frames (a HEARTBEAT too short to be one)
    with contextlib.suppress(OSError):  # the server closes while the flood is still coming
        for _ in range(100):
            attacker.sock.sendall(flood)
    assert attacker.ended.wait(5)
    assert channel.reader.rate_limited == 1
    assert attacker.errors()[-1] == (
        LIMIT_EXCEEDED,
        "more than 100 messages a second (bursts of 500): closing",
    )
    # One ERROR (too short) for each message handled: at most the burst and ~100 a second.
    assert len(attacker.named("ERROR")) - 1 <= 1000
    assert high["inbox"] <= 16 and high["rx"] <= MAX_RX_BYTES
    until(lambda: not channel.clients and not channel.hub.connections)
    assert channel.decision.state().lease_holder is None
    welcomed(server.port).close()  # and the channel serves the next client


def test_a_client_faster_than_the_loop_is_read_no_faster_than_it_is_served(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve(max_inbox=8, max_messages_per_s=1e9, max_burst=10**9)
    client = welcomed(server.port)
    side = server.client(client.port)
    high = [0]
    parse = server.channel.reader.parse

    def watched(c: PriorityClient, now: float) -> None:
        parse(c, now)
        high[0] = max(high[0], len(c.inbox))

    server.channel.reader.parse = watched  # type: ignore[method-assign]
    client.send(*(ping(seq) for seq in range(1, 3001)))
    until(lambda: len(client.named("PONG")) == 3000)
    assert [int(f["seq"]) for _, f, _ in client.named("PONG")] == list(range(1, 3001))
    assert high[0] <= 8 and len(side.rx) <= MAX_RX_BYTES
    client.close()


def test_what_waits_for_a_client_that_does_not_read_is_bounded(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve(max_inbox=8, max_messages_per_s=1e9, max_burst=10**9)
    client = RawClient(server.port, read=False, rcvbuf=4096)
    client.send(hello())
    side = server.client(client.port)
    side.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)  # a slow link
    until(lambda: side.stage is Stage.OPEN)
    # Forces until the socket is full and the channel's own queue too.
    for _ in range(200_000):
        server.sensor.emit()
        if side.forces_dropped:
            break
    assert len(side.forces) == MAX_QUEUED_FORCES and side.forces_dropped > 0
    # Commands whose replies cannot go: reading stops, nothing piles up.
    client.send(*(ping(seq) for seq in range(1, 2001)))
    until(lambda: len(side.replies) >= REPLY_PAUSE)
    time.sleep(0.2)  # the chance to go wrong
    # (+ what was in the inbox; a few may have gone meanwhile if the socket took them)
    assert len(side.replies) <= REPLY_PAUSE + 8
    assert len(side.inbox) <= 8 and len(side.rx) <= MAX_RX_BYTES
    assert len(side.forces) <= MAX_QUEUED_FORCES and not side.closed
    # The client reads at last: every reply, in order.
    client.start_reading()
    until(lambda: len(client.named("PONG")) == 2000)
    assert [int(f["seq"]) for _, f, _ in client.named("PONG")] == list(range(1, 2001))
    assert client.forces > 0
    client.close()


def test_a_client_too_far_behind_on_its_replies_is_closed() -> None:
    ours, theirs = socket.socketpair()  # theirs never reads
    try:
        ours.setblocking(False)
        ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        client = PriorityClient(ours, "test")
        reply = struct.pack("<H", 1000) + b"\x87" * 1000
        while not client.replies:  # until the socket is full
            client.push(reply, Kind.REPLY)
        while len(client.replies) < MAX_QUEUED_REPLIES:
            client.push(reply, Kind.REPLY)
            assert not client.closed
        assert len(client.replies) == MAX_QUEUED_REPLIES and not client.closed
        assert client.push(reply, Kind.REPLY) and client.closed  # the channel's thread: close it
        assert client.close_reason == f"{MAX_QUEUED_REPLIES} replies left unread"
    finally:
        ours.close()
        theirs.close()


def test_a_client_slower_than_the_forces_still_gets_the_newest_state() -> None:
    """A client that reads a little less than the 1 kHz forces bring (a loaded machine)
    keeps the socket full of forces; the one STATE slot must still go out, or a client
    waiting for the arm's state waits for ever (a joint mirror under load did)."""
    ours, theirs = socket.socketpair()
    try:
        ours.setblocking(False)
        theirs.setblocking(False)
        ours.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
        client = PriorityClient(ours, "test")
        force = m.frame(m.encode_force([(0, 0.0, (0.0,) * 6)]))
        while not client.forces:  # until the socket is full
            client.push(force, Kind.FORCE)
        state = struct.pack("<H", 200) + bytes([m.STATE.type_id]) + b"\x00" * 199
        client.push(state, Kind.STATE)
        got = b""
        for _ in range(400):  # read less than a force frame per force queued
            with contextlib.suppress(BlockingIOError):
                got += theirs.recv(len(force) - 1)
            client.push(force, Kind.FORCE)  # (push sends what fits, as the thread does)
            if state in got:
                break
        assert state in got
    finally:
        ours.close()
        theirs.close()


def test_forces_go_only_to_clients_that_said_hello(serve: Callable[..., ChannelServer]) -> None:
    server = serve(max_pending=10)
    idle = [RawClient(server.port) for _ in range(8)]
    listener = welcomed(server.port)
    until(lambda: len(server.channel.clients) == 9)
    # Its HELLO is handled on the loop after its connection is counted: wait for it.
    mine = [f"127.0.0.1:{listener.port}"]
    until(lambda: [c.peer for c in server.channel.fanout.subscribers] == mine)
    assert [c.peer for c in server.channel.fanout.subscribers] == mine
    for _ in range(50):
        server.sensor.emit()
    until(lambda: listener.forces == 50)
    time.sleep(0.05)
    assert all(c.forces == 0 and not c.messages for c in idle)
    for c in [*idle, listener]:
        c.close()


# ------------------------------------------------------------------ connection caps


def test_connections_beyond_the_caps_are_shed_or_refused(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve(max_connections=4, max_pending=2)
    channel = server.channel
    first, second = RawClient(server.port), RawClient(server.port)
    until(lambda: len(channel.clients) == 2)
    third = RawClient(server.port)  # a third waiting for HELLO sheds the oldest
    assert first.ended.wait(5)
    assert first.errors()[0][0] == LIMIT_EXCEEDED and "waiting for HELLO" in first.errors()[0][1]
    assert channel.shed == 1 and not second.ended.is_set()
    for c in (second, third):
        c.send(hello())
        until(lambda c=c: c.named("WELCOME"))
    others = [welcomed(server.port), welcomed(server.port)]  # 4 open, all welcomed
    refused = RawClient(server.port)
    assert refused.ended.wait(5)
    assert refused.errors() == [
        (LIMIT_EXCEEDED, "the priority channel has 4 connections: try again later")
    ]
    assert channel.refused == 1 and len(channel.clients) == 4
    others[0].close()
    until(lambda: len(channel.clients) == 3)
    welcomed(server.port).close()  # a slot is free again


# ------------------------------------------------------------------ accept errors, the thread


def test_accept_running_out_of_descriptors_sheds_and_keeps_serving(
    serve: Callable[..., ChannelServer],
) -> None:
    server = serve()
    channel = server.channel
    waiting = RawClient(server.port)  # says nothing: the one to shed
    until(lambda: len(channel.clients) == 1)
    accept = channel._accept_socket
    failures = [3]

    def out_of_descriptors() -> tuple[socket.socket, Any]:
        if failures[0]:
            failures[0] -= 1
            raise OSError(errno.EMFILE, os.strerror(errno.EMFILE))
        return accept()

    channel._accept_socket = out_of_descriptors  # type: ignore[method-assign]
    client = RawClient(server.port)
    client.send(hello(), ping(7))
    until(lambda: client.named("PONG"))
    assert channel.accept_errors == 3 and channel.shed == 1 and waiting.ended.wait(5)
    assert channel.restarts == 0
    client.close()


EMFILE_SERVER = """
import asyncio, json, os, resource, sys, threading
from tests.support.priority import build_channel

async def main():
    resource.setrlimit(resource.RLIMIT_NOFILE, (256, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
    channel, hub = await build_channel()
    done = asyncio.Event()
    loop = asyncio.get_running_loop()
    threading.Thread(target=lambda: (sys.stdin.read(), loop.call_soon_threadsafe(done.set)),
                     daemon=True).start()
    held = []
    while True:  # every descriptor this process may have, taken
        try:
            held.append(os.open("/dev/null", os.O_RDONLY))
        except OSError:
            break
    print("port", channel.port, flush=True)
    while channel.accept_errors < 3:  # a client is knocking: accept() fails, again
        await asyncio.sleep(0.01)
    for fd in held:
        os.close(fd)
    await done.wait()
    print(json.dumps(channel.stats()), flush=True)
    await channel.stop()
    await hub.stop()

asyncio.run(main())
"""


def test_a_server_out_of_file_descriptors_serves_again_once_some_are_free() -> None:
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen(
        [sys.executable, "-c", EMFILE_SERVER],
        cwd=root,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdin is not None and proc.stdout is not None
    try:
        port = int(proc.stdout.readline().split()[1])
        client = RawClient(port)
        client.send(hello(), ping(1))
        until(lambda: client.named("PONG"), timeout=9)
        client.close()
        proc.stdin.close()
        stats = json.loads(proc.stdout.readline())
        assert proc.wait(10) == 0
    finally:
        proc.kill()
    assert stats["accept_errors"] >= 3 and stats["restarts"] == 0


def test_an_exception_in_the_channels_thread_is_logged_and_it_goes_on(
    serve: Callable[..., ChannelServer], caplog: pytest.LogCaptureFixture
) -> None:
    server = serve()
    channel = server.channel
    accept = channel._accept_socket
    failures = [1]

    def broken() -> tuple[socket.socket, Any]:
        if failures[0]:
            failures[0] -= 1
            raise RuntimeError("a bug")
        return accept()

    channel._accept_socket = broken  # type: ignore[method-assign]
    client = welcomed(server.port)
    client.send(ping(3))
    until(lambda: client.named("PONG"))
    assert channel.restarts == 1 and "a bug" in caplog.text
    client.close()


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_a_channel_thread_that_ends_is_replaced(serve: Callable[..., ChannelServer]) -> None:
    server = serve(watchdog_s=0.05)
    channel = server.channel
    first = channel._thread
    maintain = channel._maintain

    def ends_the_thread(now: float) -> float:
        if threading.current_thread() is first:
            raise SystemExit  # not an Exception: the loop inside does not catch it
        return maintain(now)

    channel._maintain = ends_the_thread  # type: ignore[method-assign]
    until(lambda: channel._thread is not first and channel._thread.is_alive())
    assert not first.is_alive() and channel.restarts == 1
    client = welcomed(server.port)
    client.send(ping(5))
    until(lambda: client.named("PONG"))
    client.close()
