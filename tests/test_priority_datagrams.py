"""Forces as datagrams (DATAGRAMS, docs/protocol.md) against an attacker: a datagram
from a forged source gets nothing sent anywhere, the key is the server's and new at
every registration, an observer gets no datagrams at all, and what one client is sent
is bounded by its rate however the sensor bunches its samples. And a link whose
registration brings no datagram asks again, unless the server refused.

Real sockets: a real server for the protocol, a channel in this process for asking
again (the first key's datagrams dropped at its UDP send) and for the rate bound (its
clock held still). A forged source is a UDP socket bound to 127.0.0.2:
another loopback address, so another source IP, as a spoofed packet on a LAN would be."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

import telerobot.client.master.link as link_module
import telerobot.server.realtime.priority_fanout as fanout_module
from telerobot.client.master.link import PriorityLink, Reply
from telerobot.protocol import messages as m
from telerobot.server.realtime.priority_connection import PriorityClient
from telerobot.server.realtime.priority_datagrams import (
    DATAGRAM_BURST_S,
    DATAGRAM_RATE_SLACK,
    DEFAULT_FORCE_RATE_HZ,
    ForceDatagrams,
)
from tests.support import TOKEN, until
from tests.support.priority import ChannelServer, Recorder
from tests.support.servers import serving

FORGED_IP = "127.0.0.2"  # not the TCP client's 127.0.0.1


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[str, int]]:
    with serving({"TELEROBOT_HOME_POSE": "qn"}) as base:
        yield base, httpx.get(base + "api/v1/force/channel").json()["port"]


def limits(base: str) -> dict[str, int]:
    result: dict[str, int] = httpx.get(base + "api/v1/force/channel").json()["limits"]
    return result


def register(link: PriorityLink, rec: Recorder, seq: int, every: int = 1) -> Reply:
    """DATAGRAMS on TCP (the key field is the server's to fill: zeros here)."""
    link.send_raw(m.encode(m.DATAGRAMS, seq, bytes(16), every))
    return rec.reply_to(seq)


def udp_socket(bind_ip: str, port: int, timeout: float = 1.0) -> socket.socket:
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind((bind_ip, 0))
    udp.connect(("127.0.0.1", port))
    udp.settimeout(timeout)
    return udp


def received(udp: socket.socket, wait_s: float) -> list[bytes]:
    """The datagrams that came to ``udp`` until ``wait_s`` without one."""
    got = []
    udp.settimeout(wait_s)
    while True:
        try:
            got.append(udp.recv(2048))
        except TimeoutError:
            return got


def test_a_datagram_from_another_address_gets_nothing_sent_there(
    server: tuple[str, int],
) -> None:
    """An operator registers from 127.0.0.1; a datagram with its key from a forged
    source (127.0.0.2) is refused and nothing goes there, however many are sent. (The
    old server sent 1 kHz of forces to whoever sent a registered key.)"""
    base, port = server
    rec = Recorder()
    link = PriorityLink("127.0.0.1", port, TOKEN, on_force=rec.force, on_reply=rec.reply)
    victim = udp_socket(FORGED_IP, port)
    own = udp_socket("127.0.0.1", port)
    try:
        reply = register(link, rec, 11)
        assert reply.name == "DATAGRAMS", reply  # the server's key (was an ACK)
        key = bytes(reply.fields["key"])
        refused = limits(base)["datagrams_refused"]
        sent = m.encode(m.DATAGRAMS, 0, key, 1)
        for _ in range(20):
            victim.send(sent)
        assert received(victim, 1.0) == []  # amplification 0: nothing for 20 × 23 bytes
        until(lambda: limits(base)["datagrams_refused"] >= refused + 20)
        # The same key from the client's own IP address works (the port may differ from
        # its TCP connection's) …
        own.send(sent)
        first = own.recv(2048)
        assert first[:1] == bytes((m.FORCE.type_id,))
        # … and from then on fixes the port: the key from another port of the same
        # address moves nothing (a thief who saw the key in clear on the LAN).
        with udp_socket("127.0.0.1", port) as thief:
            thief.send(sent)
            assert received(thief, 0.5) == []
        assert own.recv(2048)[:1] == bytes((m.FORCE.type_id,))  # still coming here
    finally:
        link.close()
        victim.close()
        own.close()


def test_the_key_is_the_servers_and_new_at_every_registration(server: tuple[str, int]) -> None:
    base, port = server
    rec = Recorder()
    link = PriorityLink("127.0.0.1", port, TOKEN, on_reply=rec.reply)
    udp = udp_socket("127.0.0.1", port)
    try:
        ours = b"k" * 16  # a client's own key is not taken (the old protocol's)
        link.send_raw(m.encode(m.DATAGRAMS, 20, ours, 1))
        first = rec.reply_to(20)
        assert first.name == "DATAGRAMS"
        old = bytes(first.fields["key"])
        second = register(link, rec, 21)
        new = bytes(second.fields["key"])
        assert len({ours, old, new, bytes(16)}) == 4, (old, new)
        # The old key is void at once: from the client's own address, nothing.
        refused = limits(base)["datagrams_refused"]
        udp.send(m.encode(m.DATAGRAMS, 0, ours, 1))
        udp.send(m.encode(m.DATAGRAMS, 0, old, 1))
        assert received(udp, 0.5) == []
        until(lambda: limits(base)["datagrams_refused"] >= refused + 2)
        udp.send(m.encode(m.DATAGRAMS, 0, new, 1))
        assert udp.recv(2048)[:1] == bytes((m.FORCE.type_id,))
        # A third registration takes the stream back to TCP until the new key is heard
        # (the address learnt with the old one no longer counts).
        register(link, rec, 22)
        time.sleep(0.3)  # (datagrams on their way before it)
        received(udp, 0.1)
        assert received(udp, 0.5) == []
    finally:
        link.close()
        udp.close()


def test_an_observer_gets_no_datagrams(server: tuple[str, int]) -> None:
    """Without the token, DATAGRAMS is refused, the link says why and its forces come on
    TCP; the server sends nothing by UDP for anything the observer sends."""
    base, port = server
    rec = Recorder()
    watcher = PriorityLink("127.0.0.1", port, "", on_force=rec.force, datagrams=True)
    raw = PriorityLink("127.0.0.1", port, "", on_reply=rec.reply)
    udp = udp_socket("127.0.0.1", port)
    try:
        assert not watcher.operator and watcher.datagrams.startswith("tcp: "), watcher.datagrams
        assert "observer" in watcher.datagrams
        n = len(rec.forces)
        until(lambda: len(rec.forces) > n + 200)  # on TCP
        reply = register(raw, rec, 30)
        assert reply.name == "ERROR" and "operator" in reply.text, reply
        sent = limits(base)["datagrams_sent"]
        for key in (bytes(16), b"o" * 16):
            udp.send(m.encode(m.DATAGRAMS, 0, key, 1))
        assert received(udp, 0.5) == []
        assert limits(base)["datagrams_sent"] == sent
        assert watcher.datagrams_received == 0
    finally:
        watcher.close()
        raw.close()
        udp.close()


def test_a_link_registers_again_when_its_forces_come_back_on_tcp(
    server: tuple[str, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its keep-alives stop reaching the server (here: not sent; on a real link a NAT's
    new port, which the server refuses): after the server's 2 s the forces come on TCP,
    and the link asks again, for a new key, and gets them as datagrams again."""
    _, port = server
    link = PriorityLink("127.0.0.1", port, TOKEN, datagrams=True)
    try:
        until(lambda: link.datagrams == "udp" and link.datagrams_received >= 100)
        key = link._datagram_key
        monkeypatch.setattr(link_module, "DATAGRAM_KEEPALIVE_S", 3600.0)  # silent
        until(lambda: link._datagram_key not in (key, b""), timeout=10)
        monkeypatch.undo()
        until(lambda: link.datagrams == "udp")
        n = link.datagrams_received
        until(lambda: link.datagrams_received > n + 500)
    finally:
        link.close()


# ---------------------------------------------------------------- asking again
@contextlib.contextmanager
def emitting(cs: ChannelServer) -> Iterator[None]:
    """The fake sensor's samples, ~500 a second from a thread of its own (a sensor's)."""
    done = threading.Event()

    def run() -> None:
        while not done.is_set():
            cs.sensor.emit()
            time.sleep(0.002)

    thread = threading.Thread(target=run, name="test-sensor", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join(5)


@pytest.fixture
def quick(monkeypatch: pytest.MonkeyPatch) -> None:
    """The link's tries short (0.3 s, doubling up to 2 s) so a test sees several."""
    monkeypatch.setattr(link_module, "DATAGRAM_FALLBACK_S", 0.3)
    monkeypatch.setattr(link_module, "DATAGRAM_RETRY_MAX_S", 2.0)


@pytest.mark.usefixtures("quick")
def test_a_link_asks_again_when_its_first_registration_brings_no_datagram(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a lossy link the first registration may bring no datagram (its keep-alives or
    the datagrams lost, or an outage right then): here every datagram sent for the
    first key is lost on the way. The link asks again, for a new key, and gets its
    forces as datagrams. (The old link gave up after one try: forces on TCP for the
    whole session, whatever the link did next.)"""
    cs = ChannelServer()
    keys: list[bytes] = []  # the server's, in the order it gave them
    lost = [0]
    register, send = cs.channel.datagrams.register, cs.channel.datagrams.send

    def registering(client: PriorityClient, message: bytes) -> bytes:
        reply = register(client, message)
        assert client.datagram_key is not None
        keys.append(client.datagram_key)
        return reply

    def lossy(client: PriorityClient, message: bytes, addr: Any) -> None:
        if keys and client.datagram_key == keys[0]:
            lost[0] += 1  # (the first registration's: lost on the way)
            return
        send(client, message, addr)

    monkeypatch.setattr(cs.channel.datagrams, "register", registering)
    monkeypatch.setattr(cs.channel.datagrams, "send", lossy)
    rec = Recorder()
    try:
        with emitting(cs):
            link = PriorityLink("127.0.0.1", cs.port, TOKEN, on_force=rec.force, datagrams=True)
            try:
                until(
                    lambda: link.datagrams == "udp" or link.datagrams.startswith("tcp"),
                    timeout=30,
                    what=lambda: link.datagrams,
                )
                assert link.datagrams == "udp", link.datagrams  # (was "tcp: no force datagram …")
                n = link.datagrams_received
                until(lambda: link.datagrams_received > n + 100, timeout=30)
                assert link.datagram_registrations == len(keys) >= 2, (keys, lost)
                assert link._datagram_key == keys[-1] != keys[0]
                assert link.datagrams == "udp"
            finally:
                link.close()
            assert link._udp_reader is not None and not link._udp_reader.is_alive()
    finally:
        cs.close()


@pytest.mark.usefixtures("quick")
def test_a_server_that_refuses_datagrams_is_asked_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """A refusal (ERROR to the DATAGRAMS: here a server without a UDP port) is for
    good: the link asks no more, its UDP reader ends, the forces come on TCP."""
    monkeypatch.setattr(ForceDatagrams, "_socket", lambda self, host, port: None)
    cs = ChannelServer()
    rec = Recorder()
    try:
        with emitting(cs):
            link = PriorityLink("127.0.0.1", cs.port, TOKEN, on_force=rec.force, datagrams=True)
            try:
                until(lambda: link.datagrams.startswith("tcp: "), what=lambda: link.datagrams)
                assert "UDP port" in link.datagrams, link.datagrams
                reader = link._udp_reader
                assert reader is not None
                until(lambda: not reader.is_alive())
                n = len(rec.forces)
                until(lambda: len(rec.forces) > n + 200)  # on TCP, over several tries' time
                assert link.datagram_registrations == 1
                assert link.datagrams_received == 0
            finally:
                link.close()
    finally:
        cs.close()


# ---------------------------------------------------------------- the rate bound
class FrozenTime:
    """``time`` for the fan-out's module (priority_fanout.py: the sensor's thread reads
    the time there) with its clock held still: the token buckets then refill not at
    all, however slow this machine is."""

    def __init__(self) -> None:
        self.now = time.monotonic()

    def monotonic(self) -> float:
        return self.now

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)


@pytest.mark.parametrize("every", [1, 10])
def test_a_burst_of_samples_sends_no_more_than_the_rate_allows(
    every: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """2,000 samples at once (a sensor's backlog, or a forged packet's 2 s of stream)
    give one client at most its bucket's burst: the rate over ``every`` for
    ``DATAGRAM_BURST_S``; the rest are counted and dropped. The old channel sent every
    one of them (2,000 / every)."""
    cs = ChannelServer()
    rec = Recorder()
    link = PriorityLink("127.0.0.1", cs.port, TOKEN, on_reply=rec.reply)
    udp = udp_socket("127.0.0.1", cs.port)
    try:
        key = bytes(register(link, rec, 7, every).fields["key"])
        client = cs.client(link.sock.getsockname()[1])
        udp.send(m.encode(m.DATAGRAMS, 0, key, every))
        until(lambda: client.datagram_addr is not None)
        monkeypatch.setattr(fanout_module, "time", FrozenTime())
        for _ in range(2000):
            cs.sensor.emit()
        rate = DATAGRAM_RATE_SLACK * DEFAULT_FORCE_RATE_HZ / every  # (the sensor has no rate_hz)
        burst = int(max(2.0, rate * DATAGRAM_BURST_S))
        got = len(received(udp, 0.5))
        assert got == cs.channel.datagrams.sent == burst, (got, cs.channel.datagrams.sent)
        assert cs.channel.datagrams.over_rate == 2000 // every - burst
        # At the sensor's pace (or slower) nothing is held back.
        monkeypatch.undo()
        time.sleep(0.5)  # (the bucket fills)
        udp.send(m.encode(m.DATAGRAMS, 0, key, every))  # (the keep-alive: 2 s have passed)
        until(lambda: time.monotonic() - client.datagram_heard < 1.0)
        before = cs.channel.datagrams.sent
        for _ in range(20 * every):
            cs.sensor.emit()
            time.sleep(0.001)
        assert len(received(udp, 0.5)) == 20
        assert cs.channel.datagrams.sent == before + 20
    finally:
        link.close()
        udp.close()
        cs.close()
