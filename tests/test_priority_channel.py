"""The priority channel against a real server on the simulation: forces one per
message in order, commands through the same safety as /ws, HELLO first, and the
sockets marked ahead of video."""

from __future__ import annotations

import contextlib
import itertools
import math
import socket
import struct
import time
from collections.abc import Iterator

import httpx
import pytest

from telerobot.client.master.link import PriorityLink
from telerobot.drivers.base import DeviceError
from telerobot.protocol import messages as m
from telerobot.protocol.netprio import (
    DSCP_CS1,
    DSCP_EF,
    mark_high_priority,
    mark_low_priority,
)
from tests.support import TOKEN, until
from tests.support.priority import Recorder
from tests.support.servers import serving


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[str, int]]:
    with serving({"TELEROBOT_HOME_POSE": "qn"}) as base:
        yield base, httpx.get(base + "api/v1/force/channel").json()["port"]


def connect(port: int, token: str = TOKEN) -> tuple[PriorityLink, Recorder]:
    rec = Recorder()
    link = PriorityLink("127.0.0.1", port, token, on_force=rec.force, on_reply=rec.reply)
    return link, rec


def test_every_force_sample_arrives_alone_and_in_order(server: tuple[str, int]) -> None:
    base, port = server
    link, rec = connect(port)
    try:
        until(lambda: len(rec.forces) >= 500)
        seqs = [s.seq for s, _ in rec.forces[:500]]
        assert seqs == list(range(seqs[0], seqs[0] + 500))  # nothing lost, nothing batched late
        # Sensor time and receive time are the same machine's monotonic clock: never
        # negative, and not from another time base (a sanity bound, not a latency: the
        # latency on this channel is bench.force_under_video's).
        assert all(0 <= at - s.time < 30.0 for s, at in rec.forces[:500])
        state = httpx.get(base + "api/v1/force/channel").json()
        assert state["clients"] >= 1 and state["samples_sent"] >= 500
    finally:
        link.close()


def test_commands_go_through_the_lease_and_the_limits(server: tuple[str, int]) -> None:
    base, port = server
    link, rec = connect(port)
    observer, orec = connect(port, token="")
    try:
        assert link.operator and not observer.operator
        seq = observer.cartesian((0.005, 0, 0), (0, 0, 0))
        assert orec.reply_to(seq).name == "ERROR"  # observers move nothing
        assert rec.reply_to(link.lease(m.LeaseAction.TAKE)).name == "ACK"
        before = httpx.get(base + "api/v1/robot/state").json()["target_joints"]
        assert rec.reply_to(link.cartesian((0.005, 0, 0), (0, 0, 0))).name == "ACK"
        # At rest before the refusals: this link sends no heartbeats, so a busy machine's
        # slow REST calls can let the dead-man halt it, and a halt while moving leaves
        # the target where the arm stopped (at rest, where it is).
        until(lambda: httpx.get(base + "api/v1/robot/state").json()["status"] == "READY")
        after = httpx.get(base + "api/v1/robot/state").json()["target_joints"]
        assert after != before
        too_far = rec.reply_to(link.cartesian((0.05, 0, 0), (0, 0, 0)))
        assert too_far.name == "ERROR" and "per-command limit" in too_far.text
        nan = rec.reply_to(link.cartesian((math.nan, 0, 0), (0, 0, 0)))
        assert nan.name == "ERROR"
        assert httpx.get(base + "api/v1/robot/state").json()["target_joints"] == after
        # Still connected and still in control after the refusals.
        assert rec.reply_to(link.cartesian((0, 0.002, 0), (0, 0, 0))).name == "ACK"
        link.send_raw(b"\xee\x01")  # an unknown message type
        until(lambda: any(r.name == "ERROR" and "unknown" in r.text for r in rec.replies))
    finally:
        link.close()
        observer.close()
    # Closing the link gives up the lease.
    until(lambda: httpx.get(base + "api/v1/safety").json()["controller"] is None)


def test_a_master_says_its_energy_and_the_arm_answers_with_its_own(
    server: tuple[str, int],
) -> None:
    # The two-port's messages (docs/protocol.md, Passivity): an operator's ENERGY is
    # answered by the arm's PORT_ENERGY (nothing pressed yet: nothing given or spent);
    # an observer's, or one with a bad value, gets an ERROR and changes nothing.
    _, port = server
    link, rec = connect(port)
    watcher, seen = connect(port, token="")
    try:
        seq = link.energy(0.5, 0.1)
        answer = rec.reply_to(seq)
        assert answer.name == "PORT_ENERGY", answer
        assert answer.fields["e_in"] == 0.0 and answer.fields["e_out"] == 0.0
        for bad, says in ((math.nan, "e_in is nan"), (math.inf, "e_in is inf"), (-1.0, "≥ 0")):
            refused = rec.reply_to(link.energy(bad, 0.0))
            assert refused.name == "ERROR" and says in refused.text, refused
        refused = seen.reply_to(watcher.energy(1.0, 0.0))
        assert refused.name == "ERROR" and "operator" in refused.text, refused
    finally:
        link.close()
        watcher.close()


def test_the_first_message_must_be_hello(server: tuple[str, int]) -> None:
    _, port = server
    with socket.create_connection(("127.0.0.1", port), timeout=5) as sock:
        ping = m.encode(m.PING, 1, 0.0)
        sock.sendall(struct.pack("<H", len(ping)) + ping)
        data = b""
        while chunk := sock.recv(4096):  # the server answers, then closes
            data += chunk
    (size,) = struct.unpack_from("<H", data)
    msg, _, text = m.decode(data[2 : 2 + size])
    assert msg is m.ERROR and "HELLO" in text


def test_a_link_to_nowhere_says_where() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # bound, not listening: refused
    with pytest.raises(DeviceError, match=f"tcp://127.0.0.1:{port}"):
        PriorityLink("127.0.0.1", port)


def test_forces_are_marked_ahead_of_video() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as fast:
        mark_high_priority(fast)
        assert fast.getsockopt(socket.IPPROTO_IP, socket.IP_TOS) == DSCP_EF
        assert fast.getsockopt(socket.SOL_SOCKET, socket.SO_PRIORITY) == 6
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as video:
        mark_low_priority(video)
        assert video.getsockopt(socket.IPPROTO_IP, socket.IP_TOS) == DSCP_CS1
        assert video.getsockopt(socket.SOL_SOCKET, socket.SO_PRIORITY) == 1


def read_messages(sock: socket.socket, count: int, name: str) -> list[dict[str, object]]:
    """Read until ``count`` messages called ``name`` have come (the rest skipped)."""
    buf, found = b"", []
    while len(found) < count:
        chunk = sock.recv(65536)
        assert chunk, f"closed after {len(found)} {name}s"
        buf += chunk
        while len(buf) >= 2 and len(buf) >= 2 + struct.unpack_from("<H", buf)[0]:
            (size,) = struct.unpack_from("<H", buf)
            message, buf = buf[2 : 2 + size], buf[2 + size :]
            if message[0] != m.FORCE.type_id:
                msg, fields, _ = m.decode(message)
                if msg.name == name:
                    found.append(fields)
    return found


def test_messages_sent_in_the_same_write_as_hello_are_all_answered(
    server: tuple[str, int],
) -> None:
    _, port = server
    hello = m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b"")
    pings = [m.encode(m.PING, seq, 0.0) for seq in range(1, 201)]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(b"".join(struct.pack("<H", len(x)) + x for x in [hello, *pings]))
        pongs = read_messages(sock, 200, "PONG")
    assert [f["seq"] for f in pongs] == list(range(1, 201))


def test_sockets_that_never_say_hello_are_shed_then_closed(server: tuple[str, int]) -> None:
    """More idle sockets than may wait for HELLO: the oldest go first; the rest go
    when their time is up (HELLO_TIMEOUT_S); a client that says HELLO is served."""
    _, port = server
    idle = [socket.create_connection(("127.0.0.1", port), timeout=10) for _ in range(12)]
    try:
        link, _ = connect(port, token="")  # served all the same
        link.close()
        for sock in idle:  # each gets ERROR, then the end
            data = b""
            with contextlib.suppress(ConnectionResetError):
                while chunk := sock.recv(4096):
                    data += chunk
            msg, _, text = m.decode(data[2 : 2 + struct.unpack_from("<H", data)[0]])
            assert msg is m.ERROR and ("HELLO" in text), text
    finally:
        for sock in idle:
            sock.close()


# ---------------------------------------------------------------- forces as datagrams
def test_forces_come_as_datagrams_when_asked_and_commands_stay_on_tcp(
    server: tuple[str, int],
) -> None:
    base, port = server
    rec = Recorder()
    link = PriorityLink(
        "127.0.0.1", port, TOKEN, on_force=rec.force, on_reply=rec.reply, datagrams=True
    )
    try:
        until(lambda: link.datagrams == "udp" and link.datagrams_received >= 500)
        assert rec.reply_to(link._datagram_seq).name == "DATAGRAMS"  # with the server's key
        # From the switch on, every sample came by UDP (on loopback none is lost), in order.
        n, on_tcp = len(rec.forces), link.received - link.datagrams_received
        until(lambda: len(rec.forces) >= n + 300)
        seqs = [s.seq for s, _ in rec.forces[n : n + 300]]
        assert seqs == list(range(seqs[0], seqs[0] + 300))
        assert all(0 <= at - s.time < 30.0 for s, at in rec.forces[n : n + 300])
        # On TCP only until the switch: none of those 300 came by TCP (±1: the two
        # counters are not read at one instant). How long the switch took is no line here.
        assert abs(link.received - link.datagrams_received - on_tcp) <= 1, on_tcp
        limits = httpx.get(base + "api/v1/force/channel").json()["limits"]
        assert limits["datagrams_sent"] >= 500
        # Commands and their replies still travel on TCP.
        assert rec.reply_to(link.lease(m.LeaseAction.TAKE)).name == "ACK"
        assert rec.reply_to(link.cartesian((0.002, 0, 0), (0, 0, 0))).name == "ACK"
    finally:
        link.close()


def test_forces_go_back_to_tcp_when_the_datagrams_stop(server: tuple[str, int]) -> None:
    """The client's keep-alive stops (its UDP socket closed, a NAT mapping gone): after
    the server's 2 s the samples come on TCP again."""
    _, port = server
    rec = Recorder()
    link = PriorityLink("127.0.0.1", port, TOKEN, on_force=rec.force, on_reply=rec.reply)
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        udp.connect(("127.0.0.1", port))
        udp.settimeout(2)
        link.send_raw(m.encode(m.DATAGRAMS, 77, bytes(16), 1))
        registered = rec.reply_to(77)
        assert registered.name == "DATAGRAMS"
        key = bytes(registered.fields["key"])
        udp.send(m.encode(m.DATAGRAMS, 0, key, 1))
        first = udp.recv(2048)
        assert first[:1] == bytes((m.FORCE.type_id,)) and len(m.decode_force(first)) == 1
        time.sleep(0.3)  # (samples already queued on TCP have arrived)
        on_tcp = len(rec.forces)
        time.sleep(0.5)
        assert len(rec.forces) <= on_tcp + 5  # while the datagrams flow, TCP is quiet
        udp.close()  # no more keep-alives
        until(lambda: len(rec.forces) > on_tcp + 500, timeout=10)
    finally:
        link.close()
        udp.close()


def test_datagrams_without_a_registered_key_get_nothing(server: tuple[str, int]) -> None:
    base, port = server
    before = httpx.get(base + "api/v1/force/channel").json()["limits"]["datagrams_refused"]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.settimeout(0.5)
        udp.connect(("127.0.0.1", port))
        # A flood: more than the channel reads in one step (MAX_DATAGRAMS_PER_STEP, 64).
        junk = [m.encode(m.DATAGRAMS, 0, b"\x07" * 16, 1), b"", b"\x09" * 5, b"x" * 60] * 50
        for datagram in junk:
            udp.send(datagram)
        with pytest.raises(TimeoutError):
            udp.recv(2048)  # no answer, no forces
    until(
        lambda: (
            httpx.get(base + "api/v1/force/channel").json()["limits"]["datagrams_refused"]
            >= before + 150
        )  # (all but the empty ones: a zero-length read may not count)
    )


def test_a_short_datagrams_message_is_refused(server: tuple[str, int]) -> None:
    """(The key is the server's, new at every registration: test_priority_datagrams.)"""
    _, port = server
    b, brec = connect(port)
    try:
        b.send_raw(m.encode(m.DATAGRAMS, 8, bytes(16), 1)[:-1])  # a byte short
        until(lambda: any(r.name == "ERROR" and "DATAGRAMS" in r.text for r in brec.replies))
    finally:
        b.close()


def test_a_link_keeps_its_forces_on_tcp_and_asks_again_while_no_datagram_comes(
    server: tuple[str, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A firewall that drops the server's datagrams (here they go to a port nobody
    serves): the forces keep coming on TCP, and the link registers again and again,
    each try waiting twice as long as the last up to ``DATAGRAM_RETRY_MAX_S`` (short
    here): never in a tight loop, and no more once closed. (The old link stopped asking
    after one try, so one lost packet on a lossy link cost it the datagrams for good.)"""
    import telerobot.client.master.link as link_module

    monkeypatch.setattr(link_module, "DATAGRAM_FALLBACK_S", 0.2)
    monkeypatch.setattr(link_module, "DATAGRAM_RETRY_MAX_S", 0.8)
    _, port = server
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as hole:
        hole.bind(("127.0.0.1", 0))
        real_connect = socket.socket.connect

        def misdirected(self: socket.socket, address: object) -> None:
            if self.type == socket.SOCK_DGRAM:
                address = hole.getsockname()
            real_connect(self, address)  # type: ignore[arg-type]

        with monkeypatch.context() as patch:
            patch.setattr(link_module.socket.socket, "connect", misdirected)
            rec = Recorder()
            link = PriorityLink("127.0.0.1", port, TOKEN, on_force=rec.force, datagrams=True)
        try:
            until(lambda: link.datagram_registrations >= 4, timeout=30, what=lambda: link.datagrams)
            assert link.datagrams.startswith("asking (try "), link.datagrams
            assert link._datagram_wait_s == 0.8  # 0.2, 0.4, 0.8, then no longer
            n = len(rec.forces)
            until(lambda: len(rec.forces) > n + 500)  # on TCP meanwhile
            assert link.datagrams_received == 0
            # Bounded: at most one try per capped wait (a slow machine makes fewer).
            t0, tries = time.monotonic(), link.datagram_registrations
            until(lambda: link.datagram_registrations >= tries + 2, timeout=30)
            assert link.datagram_registrations - tries <= (time.monotonic() - t0) / 0.8 + 1
        finally:
            link.close()
        reader = link._udp_reader  # (the one that asks: ended, so asks no more)
        assert reader is not None and not reader.is_alive()


def test_datagrams_is_refused_on_the_websocket() -> None:
    from telerobot.server.realtime.session import handle

    replies: list[bytes] = []

    class Conn:
        def reply(self, data: bytes) -> None:
            replies.append(data)

    import asyncio

    ok = asyncio.run(
        handle(m.encode(m.DATAGRAMS, 3, b"k" * 16, 1), 0.0, "c", Conn(), None, None)  # type: ignore[arg-type]
    )
    msg, fields, text = m.decode(replies[0])
    assert not ok and msg is m.ERROR and fields["seq"] == 3 and "priority channel" in text


def test_newer_sample_numbers_wrap() -> None:
    from telerobot.client.master.link import newer

    assert newer(5, 4) and not newer(4, 5) and not newer(4, 4)
    assert newer(0, 0xFFFFFFFF) and not newer(0xFFFFFFFF, 0)


def test_every_thins_the_datagrams_and_a_bad_every_is_refused(server: tuple[str, int]) -> None:
    _, port = server
    rec = Recorder()
    link = PriorityLink("127.0.0.1", port, TOKEN, on_reply=rec.reply)
    try:
        link.send_raw(m.encode(m.DATAGRAMS, 40, b"e" * 16, 0))
        zero = rec.reply_to(40)
        assert zero.name == "ERROR" and "every" in zero.text
        link.send_raw(m.encode(m.DATAGRAMS, 39, b"e" * 16, 1001))  # past MAX_EVERY
        assert rec.reply_to(39).name == "ERROR"
        link.send_raw(m.encode(m.DATAGRAMS, 41, b"e" * 16, 1))
        registered = rec.reply_to(41)
        assert registered.name == "DATAGRAMS"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.settimeout(2)
            udp.connect(("127.0.0.1", port))
            udp.send(m.encode(m.DATAGRAMS, 0, bytes(registered.fields["key"]), 10))
            seqs = [m.decode_force(udp.recv(2048))[0][0] for _ in range(30)]
            assert all(s % 10 == 0 for s in seqs[5:]), seqs  # (a few were on their way)
            assert all(b - a == 10 for a, b in itertools.pairwise(seqs[5:])), seqs
    finally:
        link.close()


def test_thinning_doubles_on_loss_and_halves_after_a_clean_while() -> None:
    from telerobot.client.master.link import Thinning

    t = Thinning(now=0.0)
    for seq in range(1000, 1500):
        if seq % 10:  # 10 % missing
            t.arrived(seq)
    assert t.judge(0.5) == 2 and t.loss == pytest.approx(0.1, abs=0.01)
    for seq in range(1500, 2000, 2):
        if seq % 20:  # still 10 % of those sent
            t.arrived(seq)
    assert t.judge(1.0) == 4
    for k in range(16):  # up to the cap
        for seq in range(2000 + 500 * k, 2500 + 500 * k, t.every):
            if (seq // t.every) % 10:
                t.arrived(seq)
        t.judge(1.5 + 0.5 * k)
    assert t.every == Thinning.MAX
    now = 10.0
    for _ in range(4):  # clean: halves every 2 s, not sooner
        start = 100_000 + int(now * 1000)
        for seq in range(start, start + 500):
            t.arrived(seq)
        now += 0.5
        t.judge(now)
    assert t.every == Thinning.MAX // 2
    # Some loss under the doubling limit holds it; nothing heard at all says nothing.
    assert t.judge(now + 5) == Thinning.MAX // 2


def test_thinning_ignores_samples_sent_before_the_change_and_wraps() -> None:
    from telerobot.client.master.link import Thinning

    t = Thinning(now=0.0)
    t.every = 4
    for seq in [0xFFFFFFF0 + i for i in range(0, 16)] + list(range(0, 64)):
        t.arrived(seq)  # only the multiples of 4 count; the rest came before the change
    assert t.judge(0.5) == 4 and t.loss == 0.0
