"""The binary WebSocket channel against the real app (in-process ASGI), in virtual time."""

from __future__ import annotations

import math
import struct
from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from starlette.websockets import WebSocketDisconnect

from telerobot.drivers.clock import ManualClock
from telerobot.protocol import messages as m
from telerobot.server.app import create_app
from telerobot.server.settings import Settings
from tests.support import TOKEN

WS = "ws://localhost/ws"  # TestClient says "testserver" unless told: not a name we answer to


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
def client(clock: ManualClock) -> Iterator[TestClient]:
    settings = Settings(home_pose="qz", operator_token=TOKEN)  # the sim starts at qz: READY at once
    with TestClient(create_app(settings, clock=clock), base_url="http://localhost") as tc:
        tc.portal.call(clock.advance, 0.1)  # type: ignore[union-attr]
        yield tc


def hello(token: str = "", flags: int = 0) -> bytes:
    return m.encode(m.HELLO, m.PROTOCOL_VERSION, flags, token.encode())


def receive_until(
    ws, wanted: m.Message, limit: int = 200
) -> tuple[dict[str, object], str, list[bytes]]:  # type: ignore[no-untyped-def]
    """Read messages until one of type ``wanted``; returns its fields, text and what came before."""
    skipped = []
    for _ in range(limit):
        data = ws.receive_bytes()
        if data[0] == wanted.type_id:
            if wanted is m.FORCE:
                return {"samples": m.decode_force(data)}, "", skipped
            _, fields, text = m.decode(data)
            return fields, text, skipped
        skipped.append(data)
    raise AssertionError(f"no {wanted.name} in {limit} messages")


def cart(seq: int, dx: float = 0.001, frame: int = 0, nan: bool = False) -> bytes:
    return m.encode(m.CART_INC, seq, 1.0, frame, math.nan if nan else dx, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_observer_is_welcomed_sees_state_and_cannot_move(
    client: TestClient, clock: ManualClock
) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello())
        welcome, client_id, _ = receive_until(ws, m.WELCOME)
        assert welcome["role"] == 0 and welcome["version"] == m.PROTOCOL_VERSION and client_id
        state, _, _ = receive_until(ws, m.STATE)
        assert state["status"] == 3  # READY
        assert not int(state["flags"]) & m.StateFlags.OPERATOR  # type: ignore[call-overload]
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        err, text, _ = receive_until(ws, m.ERROR)
        assert (
            err["seq"] == 1
            and err["code"] == m.ERROR_CODES["not_allowed"]
            and "operator token" in text
        )
        ws.send_bytes(cart(2))
        err, _, _ = receive_until(ws, m.ERROR)
        assert err["seq"] == 2 and err["code"] == m.ERROR_CODES["not_allowed"]
    assert client.get("/api/v1/robot/state").json()["target_joints"] == pytest.approx([0] * 6)


def test_welcome_says_the_joint_count_and_a_joint_increment_moves_each_joint(
    client: TestClient, clock: ManualClock
) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN))
        welcome, _, _ = receive_until(ws, m.WELCOME)
        assert welcome["joints"] == 6
        state, _, _ = receive_until(ws, m.STATE)
        assert state["joints"] == pytest.approx([0.0] * 6)  # the sim starts at qz
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(ws, m.ACK)
        step = [0.002, -0.004, 0.003, 0.0, 0.001, -0.001]  # done before the dead-man acts
        ws.send_bytes(m.encode(m.JOINT_INC, 2, 0.0, joints=step))
        ack, _, _ = receive_until(ws, m.ACK)
        assert ack["seq"] == 2
        client.portal.call(clock.advance, 1.0)  # type: ignore[union-attr]
        ws.send_bytes(m.encode(m.HEARTBEAT, 3, 0.0))
        assert ack["result"] == m.Ack.APPLIED
        assert client.get("/api/v1/robot/state").json()["joints"] == pytest.approx(step, abs=1e-9)
        for _ in range(20):  # the STATEs queued before the move ended, then the new one
            state, _, _ = receive_until(ws, m.STATE)
            if state["joints"] == pytest.approx(step, abs=1e-9):
                break
        else:
            raise AssertionError(f"STATE never showed the joints moved: {state['joints']}")


def test_operator_takes_control_and_moves(client: TestClient, clock: ManualClock) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN))
        welcome, _, _ = receive_until(ws, m.WELCOME)
        assert welcome["role"] == 1
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        ack, _, _ = receive_until(ws, m.ACK)
        assert ack["seq"] == 1
        x0 = client.get("/api/v1/robot/state").json()["position"][0]
        ws.send_bytes(cart(2, dx=0.004))
        ack, _, _ = receive_until(ws, m.ACK)
        assert ack["seq"] == 2 and ack["result"] == m.Ack.APPLIED
        client.portal.call(clock.advance, 1.0)  # type: ignore[union-attr]
        ws.send_bytes(m.encode(m.HEARTBEAT, 3, 0.0))
        state, _, _ = receive_until(ws, m.STATE)
        assert int(state["flags"]) & m.StateFlags.YOU_HAVE_CONTROL  # type: ignore[call-overload]
        assert client.get("/api/v1/robot/state").json()["position"][0] == pytest.approx(
            x0 + 0.004, abs=1e-6
        )


@pytest.mark.parametrize(
    ("frame", "why"),
    [
        (b"", "empty"),
        (b"\x7f\x00\x00", "unknown message type 0x7f"),
        (cart(5)[:-1], "CART_INC must be 63 bytes, got 62"),
        (cart(5) + b"\x00", "CART_INC must be 63 bytes, got 64"),
        (cart(5, nan=True), "CART_INC.dx is nan"),
        (cart(5, frame=9), "unknown frame 9"),
        (m.encode(m.LEASE, 5, 7), "unknown lease action 7"),
        (m.encode(m.ACK, 5, 0, 0.0, 1.0), "ACK is not a client message"),
        # The joints: as many as the arm has (6), finite, whole, at most MAX_JOINTS.
        (m.encode(m.JOINT_INC, 5, 1.0, joints=[0.01] * 5), "must have 6 values"),
        (m.encode(m.JOINT_INC, 5, 1.0, joints=[0, 0, math.nan, 0, 0, 0]), "has NaN"),
        (m.encode(m.JOINT_INC, 5, 1.0, joints=[0.01] * 6)[:-1], "JOINT_INC must be 14 + 8"),
        (m.encode(m.JOINT_INC, 5, 1.0, joints=[0.0] * 17), "(≤ 16)"),
    ],
)
def test_malformed_frames_get_an_error_and_nothing_moves(
    client: TestClient, frame: bytes, why: str
) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN))
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(ws, m.ACK)
        ws.send_bytes(frame)
        err, text, _ = receive_until(ws, m.ERROR)
        assert why in text and err["code"] in m.ERROR_CODES.values()
        # The connection is still up and serving.
        ws.send_bytes(m.encode(m.PING, 6, 123.5))
        pong, _, _ = receive_until(ws, m.PONG)
        assert pong["seq"] == 6 and pong["t0"] == 123.5
    assert client.get("/api/v1/robot/state").json()["target_joints"] == pytest.approx([0] * 6)


def test_text_frames_are_refused_politely(client: TestClient) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello())
        ws.send_text("move please")
        _, text, _ = receive_until(ws, m.ERROR)
        assert "binary messages only" in text


def test_a_client_that_does_not_say_hello_is_closed(client: TestClient) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(m.encode(m.PING, 1, 0.0))
        _, text, _ = receive_until(ws, m.ERROR)
        assert "first message must be HELLO" in text
        with pytest.raises(WebSocketDisconnect):
            ws.receive_bytes()


def test_foreign_origin_is_refused(client: TestClient) -> None:
    with (
        pytest.raises(WebSocketDisconnect) as exc,
        client.websocket_connect(WS, headers={"origin": "https://evil.example"}) as ws,
    ):
        ws.receive_bytes()
    assert exc.value.code == 1008
    with client.websocket_connect(WS, headers={"origin": "http://localhost"}) as ws:  # same host
        ws.send_bytes(hello())
        receive_until(ws, m.WELCOME)


def test_estop_from_an_observer_latches_until_the_operator_resets(client: TestClient) -> None:
    with client.websocket_connect(WS) as op, client.websocket_connect(WS) as watcher:
        op.send_bytes(hello(TOKEN))
        op.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(op, m.ACK)
        watcher.send_bytes(hello())
        receive_until(watcher, m.WELCOME)
        watcher.send_bytes(m.encode(m.ESTOP, 1, 0.0))
        receive_until(watcher, m.ACK)
        op.send_bytes(cart(2))
        err, text, _ = receive_until(op, m.ERROR)
        assert err["code"] == m.ERROR_CODES["safety_stop"] and "e-stop is latched" in text
        op.send_bytes(m.encode(m.RESET, 3))
        ack, _, _ = receive_until(op, m.ACK)
        assert ack["seq"] == 3
        op.send_bytes(cart(4))
        ack, _, _ = receive_until(op, m.ACK)
        assert ack["seq"] == 4


def test_a_client_names_itself_in_its_ws_url_and_is_shown_by_that_name(
    client: TestClient,
) -> None:
    """``/ws?name=`` names the client (the HELLO stays as it is):
    who has control is that name in GET /safety and in every viewer's SAFETY event, not
    "ws 127.0.0.1:51186"; without a name it is still its address."""
    name = "Ana at the bench"
    with (
        client.websocket_connect(f"{WS}?name=Ana%20at%20the%20bench") as op,
        client.websocket_connect(WS) as watcher,
    ):
        watcher.send_bytes(hello())
        receive_until(watcher, m.WELCOME)
        op.send_bytes(hello(TOKEN))
        receive_until(op, m.WELCOME)
        op.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(op, m.ACK)
        assert client.get("/api/v1/safety").json()["controller"] == name
        for _ in range(10):  # the lease's SAFETY event (a STATUS one may come first)
            event, text, _ = receive_until(watcher, m.EVENT)
            if event["kind"] == m.EventKind.SAFETY:
                break
        assert text.startswith(f"control: {name} (taken by {name!r})"), text
        op.send_bytes(m.encode(m.LEASE, 2, m.LeaseAction.RELEASE))
        receive_until(op, m.ACK)
    with client.websocket_connect(WS) as unnamed:
        unnamed.send_bytes(hello(TOKEN))
        unnamed.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(unnamed, m.ACK)
        assert client.get("/api/v1/safety").json()["controller"].startswith("ws ")


def test_a_client_with_no_url_names_itself_with_name_and_a_bad_name_keeps_the_old(
    client: TestClient,
) -> None:
    """NAME (the master bridge's way, on the priority channel, which has no URL): the
    holder's new name is said at once; one against the rule gets ERROR saying why and
    the old name stays."""
    with client.websocket_connect(WS) as op:
        op.send_bytes(hello(TOKEN))
        receive_until(op, m.WELCOME)
        op.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(op, m.ACK)
        assert client.get("/api/v1/safety").json()["controller"].startswith("ws ")
        op.send_bytes(m.encode(m.NAME, 2, text="master sim-leader"))
        ack, _, before = receive_until(op, m.ACK)
        assert ack["seq"] == 2
        said = [m.decode(d) for d in before if d[0] == m.EVENT.type_id]  # (said before ACK)
        said = [text for _, f, text in said if f["kind"] == m.EventKind.SAFETY]
        assert said and said[-1].startswith("control: master sim-leader"), said
        op.send_bytes(m.encode(m.NAME, 3, text="(me); drop"))
        err, text, _ = receive_until(op, m.ERROR)
        assert err["seq"] == 3 and err["code"] == m.ERROR_CODES["invalid_command"], err
        assert text.startswith("a name is 1–64 characters"), text
        assert client.get("/api/v1/safety").json()["controller"] == "master sim-leader"


@pytest.mark.parametrize("bad", ["", "a%3Bb", "x" * 65, "two%0Alines", "(me)"])
def test_a_name_that_cannot_be_shown_as_it_is_is_refused_saying_how(
    client: TestClient, bad: str
) -> None:
    with client.websocket_connect(f"{WS}?name={bad}") as ws:
        err, text, _ = receive_until(ws, m.ERROR)
        assert err["code"] == m.ERROR_CODES["invalid_command"], err
        assert text.startswith("name: a name is 1–64 characters: letters, digits"), text
        with pytest.raises(WebSocketDisconnect) as closed:
            ws.receive_bytes()
        assert closed.value.code == 1008
    assert client.get("/api/v1/safety").json()["controller"] is None


def test_force_samples_one_by_one_or_batched(client: TestClient) -> None:
    with client.websocket_connect(WS) as every, client.websocket_connect(WS) as batched:
        every.send_bytes(hello(flags=m.HelloFlags.EVERY_FORCE_SAMPLE))
        batched.send_bytes(hello())
        lost_before = client.get("/api/v1/force").json()["counters"].get("lost", 0)
        seqs: list[int] = []
        while len(seqs) < 30:
            fields, _, _ = receive_until(every, m.FORCE)
            samples = fields["samples"]
            assert isinstance(samples, list) and len(samples) >= 1
            seqs += [s[0] for s in samples]
        lost = client.get("/api/v1/force").json()["counters"].get("lost", 0) - lost_before
        # In order, and none lost on the way: a number missing is one the simulated
        # sensor itself skipped (its thread stalled past 0.1 s on a loaded machine: it
        # counts those as lost, as a real sensor's dropped packets).
        assert seqs == sorted(set(seqs))
        assert seqs[-1] - seqs[0] + 1 - len(seqs) <= lost, (seqs, lost)
        sizes = [len(receive_until(batched, m.FORCE)[0]["samples"]) for _ in range(5)]  # type: ignore[arg-type]
        assert max(sizes) > 1


def test_ping_reports_server_receive_and_send_times(client: TestClient, clock: ManualClock) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello())
        ws.send_bytes(m.encode(m.PING, 9, 42.0))
        pong, _, _ = receive_until(ws, m.PONG)
        assert (
            pong["t0"] == 42.0
            and pong["t1"] == pytest.approx(clock.now())
            and pong["t2"] >= pong["t1"]
        )  # type: ignore[operator]


def test_every_message_layout_is_documented() -> None:
    from pathlib import Path

    doc = (Path(__file__).parent.parent / "docs" / "protocol.md").read_text()
    for msg in m.MESSAGES:
        row = f"| `{msg.name}` | 0x{msg.type_id:02x} |"
        assert row in doc, f"docs/protocol.md lacks the row for {msg.name}: {row}"
        assert f"`<B{msg.fmt}`" in doc, f"docs/protocol.md has a stale layout for {msg.name}"
    assert struct.calcsize("<Id6d") == m.FORCE_SAMPLE.size == 60


def test_pings_alone_do_not_keep_the_dead_man_satisfied(
    client: TestClient, clock: ManualClock
) -> None:
    # The page's worker pings every 2 s for the clock sync, also while the page hangs:
    # a ping is not the operator being there.
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN))
        receive_until(ws, m.WELCOME)
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(ws, m.ACK)
        for seq in range(2, 12):
            ws.send_bytes(m.encode(m.PING, seq, 0.0))
            receive_until(ws, m.PONG)
            client.portal.call(clock.advance, 0.05)  # type: ignore[union-attr]
        assert client.get("/api/v1/safety").json()["halted"] is True


def test_a_synced_clients_stale_command_is_dropped_with_its_age(
    client: TestClient, clock: ManualClock
) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN, flags=m.HelloFlags.SYNCED_CLOCK))
        receive_until(ws, m.WELCOME)
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(ws, m.ACK)
        x0 = client.get("/api/v1/robot/state").json()["position"][0]
        old = clock.now() - 0.3  # sent 300 ms ago on the server's clock
        ws.send_bytes(m.encode(m.CART_INC, 2, old, 0, 0.004, 0.0, 0.0, 0.0, 0.0, 0.0))
        error, text, _ = receive_until(ws, m.ERROR)
        assert error["seq"] == 2 and "sent 300 ms ago" in text, text
        fresh = clock.now() - 0.05
        ws.send_bytes(m.encode(m.CART_INC, 3, fresh, 0, 0.004, 0.0, 0.0, 0.0, 0.0, 0.0))
        ack, _, _ = receive_until(ws, m.ACK)
        assert ack["seq"] == 3 and ack["result"] == m.Ack.APPLIED
        safety = client.get("/api/v1/safety").json()
        assert safety["stale_commands_dropped"] == 1 and safety["max_command_age_ms"] == 250
        client.portal.call(clock.advance, 1.0)  # type: ignore[union-attr]
        x1 = client.get("/api/v1/robot/state").json()["position"][0]
        assert x1 == pytest.approx(x0 + 0.004, abs=1e-6)  # only the fresh one moved


def test_a_stalled_session_resumes_on_a_new_connection_with_its_lease(
    client: TestClient, clock: ManualClock
) -> None:
    resumable = m.HelloFlags.SYNCED_CLOCK | m.HelloFlags.RESUMABLE
    with client.websocket_connect(WS) as old:
        old.send_bytes(hello(TOKEN, resumable))
        _, text, _ = receive_until(old, m.WELCOME)
        client_id, key = text.split(" ")
        assert len(key) == 32
        old.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        receive_until(old, m.ACK)
        holder = client.get("/api/v1/safety").json()["controller"]
        assert holder is not None
        # The old connection goes silent for 1 s: the arm is halted, the lease kept.
        client.portal.call(clock.advance, 1.0)  # type: ignore[union-attr]
        assert client.get("/api/v1/safety").json()["halted"] is True
        # A wrong key: refused, said why, nothing changes.
        with client.websocket_connect(WS) as thief:
            thief.send_bytes(hello("x" * 32, m.HelloFlags.RESUME))
            _, why, _ = receive_until(thief, m.ERROR)
            assert "no session to resume" in why
        with client.websocket_connect(WS) as new:
            new.send_bytes(hello(key, resumable | m.HelloFlags.RESUME))
            welcome, text, _ = receive_until(new, m.WELCOME)
            same_id, key = text.split(" ")  # a key resumes once: here is the next
            assert same_id == client_id and welcome["role"] == 1  # same client
            safety = client.get("/api/v1/safety").json()
            assert safety["controller"] == holder and safety["halted"] is False
            # The stalled connection's backlog, arriving late, is dropped unread…
            x0 = client.get("/api/v1/robot/state").json()["position"][0]
            old.send_bytes(cart(2, dx=0.004))
            old.send_bytes(m.encode(m.LEASE, 3, m.LeaseAction.RELEASE))
            # …and its closing does not end the session: the new connection drives.
            old.close()
            client.portal.call(clock.advance, 0.05)  # type: ignore[union-attr]
            new.send_bytes(m.encode(m.HEARTBEAT, 4, 0.0))
            state, _, _ = receive_until(new, m.STATE)
            assert int(state["flags"]) & m.StateFlags.YOU_HAVE_CONTROL  # type: ignore[call-overload]
            assert client.get("/api/v1/robot/state").json()["position"][0] == x0
            assert client.get("/api/v1/safety").json()["controller"] == holder
        # The session ends with its connection: the key resumes nothing any more.
        with client.websocket_connect(WS) as late:
            late.send_bytes(hello(key, m.HelloFlags.RESUME))
            _, why, _ = receive_until(late, m.ERROR)
            assert "no session to resume" in why
    assert client.get("/api/v1/safety").json()["controller"] is None


def test_a_client_that_did_not_ask_gets_no_resume_key(client: TestClient) -> None:
    with client.websocket_connect(WS) as ws:
        ws.send_bytes(hello(TOKEN))
        _, text, _ = receive_until(ws, m.WELCOME)
        assert " " not in text
