"""The priority channel against a real server on the simulation: forces one per
message in order, commands through the same safety as /ws, HELLO first, and the
sockets marked ahead of video."""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterator

import httpx
import pytest

from backend.master.link import PriorityLink, Reply
from backend.netprio import (
    DSCP_CS1,
    DSCP_EF,
    mark_high_priority,
    mark_low_priority,
)
from backend.realtime import messages as m
from drivers.base import DeviceError, ForceSample
from tests.servers import telerobot

TOKEN = "priority-channel-token-0123456789"


def until(condition: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


@pytest.fixture(scope="module")
def server() -> Iterator[tuple[str, int]]:
    env = {"TELEROBOT_OPERATOR_TOKEN": TOKEN, "TELEROBOT_HOME_POSE": "qn"}
    with telerobot("serve", "--http-port", "0", wait_for=r"(http://localhost:\d+/)", env=env) as (
        _,
        match,
    ):
        base = match.group(1)
        until(lambda: httpx.get(base + "api/v1/robot/state").json()["status"] == "READY")
        yield base, httpx.get(base + "api/v1/force/channel").json()["port"]


class Recorder:
    def __init__(self) -> None:
        self.forces: list[tuple[ForceSample, float]] = []
        self.replies: list[Reply] = []
        self.lock = threading.Lock()

    def force(self, sample: ForceSample, at: float) -> None:
        self.forces.append((sample, at))

    def reply(self, r: Reply) -> None:
        with self.lock:
            self.replies.append(r)

    def reply_to(self, seq: int) -> Reply:
        until(lambda: any(r.fields.get("seq") == seq for r in list(self.replies)))
        return next(r for r in list(self.replies) if r.fields.get("seq") == seq)


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
        # Sensor time and receive time are the same machine's monotonic clock.
        assert all(0 <= at - s.time < 1.0 for s, at in rec.forces[:500])
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
