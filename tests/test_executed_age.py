"""Every executed command's age as it went to the driver (issue 34): on ``Applied``,
in ``GET /api/v1/safety`` (all clients and one client's own, bounded) and on the
recording's ``/commands``, all in virtual time. The age is the one the last check
measured, the driver's call next: the ACK's ``server_time`` (``applied_at``) comes after
that call, so it is later by the driver's own time and is no measure of the age at
execution."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from telerobot.drivers.base import FloatArray
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.protocol import messages as m
from telerobot.server.api.control import command_ages
from telerobot.server.app import create_app
from telerobot.server.control import freshness
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import SafetyStop
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.recording import reader
from telerobot.server.recording.recorder import Recorder, RecordingTaps
from telerobot.server.settings import Settings
from telerobot.server.telemetry.stats import StreamTally
from tests.support import TOKEN, until
from tests.support.clock import run_with_clock
from tests.support.decision import RecordingPuma, make

STEP = np.array([1e-4, 0.0, 0.0])
ZERO = np.zeros(3)


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


async def synced(clock: ManualClock) -> tuple[DecisionServer, RecordingPuma, str]:
    ds, robot = await make(clock)
    a = ds.join("alice", TOKEN, synced_clock=True)
    await ds.take_lease(a.id)
    return ds, robot, a.id


async def test_a_synced_clients_command_carries_its_age_at_the_driver(clock: ManualClock) -> None:
    """Sent 100 ms ago, it arrives; another command's move holds the driver 50 ms more:
    its age is taken at the driver (150 ms), not on arrival."""
    ds, robot, a = await synced(clock)
    applied = await ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.12)
    assert applied.age == pytest.approx(0.12)
    async with ds.arms[0].lock:  # another command's move in flight
        pending = asyncio.create_task(
            ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.1)
        )
        await asyncio.sleep(0)  # past the first check, waiting for the driver
        await clock.advance(0.05)
    applied = await pending
    assert applied.age == pytest.approx(0.15) and len(robot.sent) == 2
    client = ds.clients.get(a)
    assert client.executed_age is not None and client.executed_age.count == 2
    assert client.executed_age.largest == pytest.approx(150.0)
    assert ds.ages.executed_ms.count == 2 and ds.ages.executed_ms.over == 0


class SlowDriver(RecordingPuma):
    """A driver whose call returns 30 ms after it took the target (a write that waits)."""

    slow_s = 0.0  # set once initialised

    async def _send_target(self, raw_target: FloatArray) -> None:
        await super()._send_target(raw_target)
        await self.clock.sleep(self.slow_s)


async def test_the_ack_time_is_later_than_the_execution_by_the_drivers_own_time(
    clock: ManualClock,
) -> None:
    """Taken at 240 ms, within the limit; its ACK's server time (``applied_at``) says
    270 ms, which the bench's client-side figure would count as stale executed: the
    server's age tells the two apart."""
    kin = Puma560Kinematics(tool_transform(0.1))
    robot = SlowDriver(clock=clock, kinematics=kin, start_joints=NAMED_POSES["qn"])
    await robot.connect()
    await run_with_clock(clock, robot.initialize())
    robot.slow_s = 0.03
    ds = DecisionServer(
        [ArmGuard("arm", 1, robot, kin, SafetyLimits())], clock=clock, operator_token=TOKEN
    )
    a = ds.join("alice", TOKEN, synced_clock=True)
    await ds.take_lease(a.id)
    sent = clock.now() - 0.24
    applied = await run_with_clock(
        clock, ds.cartesian_increment(a.id, STEP, ZERO, client_time=sent), step=0.01
    )
    assert applied.age == pytest.approx(0.24)
    assert applied.applied_at - sent == pytest.approx(0.27)
    assert ds.ages.executed_ms.over == 0 and ds.ages.executed_ms.largest == pytest.approx(240.0)


async def test_no_age_for_a_client_off_our_clock_or_a_command_without_a_send_time(
    clock: ManualClock,
) -> None:
    ds, robot = await make(clock)
    own = ds.join("own clock", TOKEN)  # its client_time is its own clock: no age known
    await ds.take_lease(own.id)
    applied = await ds.cartesian_increment(own.id, STEP, ZERO, client_time=5.0)
    assert applied.age is None and own.executed_age is None
    s = ds.join("synced", TOKEN, synced_clock=True)
    await ds.take_lease(s.id, force=True)
    applied = await ds.cartesian_increment(s.id, STEP, ZERO)  # REST: no send time
    assert applied.age is None and s.executed_age is None
    assert ds.ages.executed_ms.count == 0 and len(robot.sent) == 2
    assert command_ages(ds.ages.executed_ms).max is None


async def test_a_stale_command_is_refused_and_never_counted_as_executed(
    clock: ManualClock,
) -> None:
    ds, robot, a = await synced(clock)
    with pytest.raises(SafetyStop, match="stale command"):
        await ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.26)
    assert ds.ages.executed_ms.count == 0 and ds.clients.get(a).executed_age is None
    assert robot.sent == []


def test_the_tally_keeps_its_window_and_never_forgets_the_worst() -> None:
    """At its capacity the window rolls; the count, the largest and the count over the
    limit are over everything since the start."""
    tally = StreamTally("ages", capacity=4, limit=250.0)
    for value in (260.0, 10.0, 20.0, 30.0, 40.0, 50.0):
        tally.record(value)
    assert tally.values().tolist() == [20.0, 30.0, 40.0, 50.0]
    view = command_ages(tally)
    assert (view.count, view.window, view.max, view.over_limit) == (6, 4, 260.0, 1)
    assert view.p50 == pytest.approx(35.0)


async def test_each_clients_figure_and_the_servers_are_bounded(
    clock: ManualClock, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Six commands against windows of four (the settings' EXECUTED_AGE_WINDOW and
    CLIENT_AGE_WINDOW, made small): each keeps four, counts six."""
    monkeypatch.setattr(freshness, "EXECUTED_AGE_WINDOW", 4)
    monkeypatch.setattr(freshness, "CLIENT_AGE_WINDOW", 4)
    ds, _, a = await synced(clock)
    for i in range(6):
        await ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.01 * (i + 1))
    client = ds.clients.get(a).executed_age
    assert client is not None
    for tally in (client, ds.ages.executed_ms):
        assert tally.capacity == 4 and len(tally.values()) == 4 and tally.count == 6
        assert tally.values().tolist() == pytest.approx([30.0, 40.0, 50.0, 60.0])


# ---------------------------------------------------------------- through the app
@pytest.fixture
def app(clock: ManualClock) -> Iterator[TestClient]:
    settings = Settings(home_pose="qz", operator_token=TOKEN)  # the sim starts at qz: READY
    with TestClient(create_app(settings, clock=clock), base_url="http://localhost") as tc:
        tc.portal.call(clock.advance, 0.1)  # type: ignore[union-attr]
        yield tc


def until_type(ws, wanted: m.Message) -> tuple[dict[str, object], str]:  # type: ignore[no-untyped-def]
    for _ in range(200):
        data = ws.receive_bytes()
        if data[0] == wanted.type_id:
            _, fields, text = m.decode(data)
            return fields, text
    raise AssertionError(f"no {wanted.name}")


def cart(seq: int, client_time: float) -> bytes:
    return m.encode(m.CART_INC, seq, client_time, 0, 0.0005, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_safety_reports_every_executed_commands_age_and_one_clients_own(
    app: TestClient, clock: ManualClock
) -> None:
    with app.websocket_connect("ws://localhost/ws") as ws:
        ws.send_bytes(
            m.encode(m.HELLO, m.PROTOCOL_VERSION, m.HelloFlags.SYNCED_CLOCK, TOKEN.encode())
        )
        _, text = until_type(ws, m.WELCOME)
        me = text.split(" ")[0]
        ws.send_bytes(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        until_type(ws, m.ACK)
        for seq, age in ((2, 0.05), (3, 0.12)):
            ws.send_bytes(cart(seq, clock.now() - age))
            ack, _ = until_type(ws, m.ACK)
            assert ack["seq"] == seq  # executed (limited: no time between them)
        ws.send_bytes(cart(4, clock.now() - 0.3))  # stale: refused, no age
        until_type(ws, m.ERROR)
        op = {"Authorization": f"Bearer {TOKEN}"}
        safety = app.get("/api/v1/safety", params={"client": me}, headers=op).json()
        everyone = app.get("/api/v1/safety").json()
        # A client's own ages are the operator's to read: no id in a tokenless answer
        refused = app.get("/api/v1/safety", params={"client": me})
        assert refused.status_code == 403 and "operator token" in refused.json()["detail"]
    mine = safety["executed_age_ms_client"]
    assert (mine["count"], mine["window"], mine["over_limit"]) == (2, 2, 0)
    assert mine["p50"] == pytest.approx(85.0) and mine["max"] == pytest.approx(120.0)
    assert everyone["executed_age_ms"]["count"] == 2
    assert everyone["executed_age_ms"]["max"] == pytest.approx(120.0)
    assert everyone["executed_age_ms_client"] is None
    assert safety["stale_commands_dropped"] == 1
    # Once the client has left, its figures go with it; the server's stay.
    until(
        lambda: (
            app.get("/api/v1/safety", params={"client": me}, headers=op).json()[
                "executed_age_ms_client"
            ]
            is None
        ),
        what="the client's figures after it left",
    )
    assert app.get("/api/v1/safety").json()["executed_age_ms"]["count"] == 2


# ---------------------------------------------------------------- the recording
async def test_the_recordings_commands_carry_each_executed_commands_age(
    clock: ManualClock, tmp_path: Path
) -> None:
    ds, _robot, a = await synced(clock)
    rec = Recorder(tmp_path, clock)
    taps = RecordingTaps(rec, decision=ds, clock=clock, state_period=1.0)
    path = rec.start("ages")
    taps.start()
    await ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.08)
    with pytest.raises(SafetyStop):
        await ds.cartesian_increment(a, STEP, ZERO, client_time=clock.now() - 0.3)
    await ds.cartesian_increment(a, STEP, ZERO)  # no send time (as REST)
    await taps.stop()
    await rec.stop()
    commands = [c for _t, _ns, c in reader.read(path, ["/commands"])]
    increments = [c for c in commands if c["kind"] == "cartesian_increment"]
    assert [c["accepted"] for c in increments] == [True, False, True]
    assert increments[0]["age_ms"] == pytest.approx(80.0)
    assert increments[1]["age_ms"] is None and increments[2]["age_ms"] is None
    assert all(c["age_ms"] is None for c in commands if c["kind"] != "cartesian_increment")
