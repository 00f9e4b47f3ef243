"""The SO-101 path on a busy machine: a start-up the bus does not answer is
tried again (with the bus emulator on a real pty and TCP port), ``POST
/robot/initialize`` takes an empty body, and a leader waiting for an arm that cannot
come to rest says why."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from telerobot.client.master.joints import JointMirror
from telerobot.client.master.link import Reply
from telerobot.drivers.base import DeviceError, NotReady, RobotStatus
from telerobot.drivers.master.sim_leader import SimLeader
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.bus import NoAnswer
from telerobot.drivers.motors.feetech.protocol import Register
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.arm import So101Arm
from telerobot.drivers.robot.so101.calibration import So101Calibration
from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator
from telerobot.protocol import messages as m
from tests.support import TOKEN, until_async

MODEL = load_model("so101")
CAL = So101Calibration.nominal(MODEL.joint_names)
AUTH = {"Authorization": f"Bearer {TOKEN}"}
# A servo has this long to answer: the emulator is a thread of this process, which a
# loaded machine can keep off the CPU for longer than a real servo's 30 ms.
REPLY_TIMEOUT = 0.25
LOG = "telerobot.drivers.robot.so101.arm"


@pytest.fixture(params=["pty", "tcp"])
def link(request: pytest.FixtureRequest) -> Iterator[BusLink]:
    steps = dict(zip(CAL.ids, map(float, CAL.to_steps(MODEL.pose("rest"))), strict=True))
    make = BusLink.on_pty if request.param == "pty" else BusLink.on_tcp
    with make(FeetechBusEmulator(start=steps)) as running:
        yield running


def mute_all(link: BusLink, muted: bool) -> None:
    for i in CAL.ids:
        link.servo(i).mute = muted


def arm_on(link: BusLink, **kw: object) -> So101Arm:
    kw.setdefault("reply_timeout", REPLY_TIMEOUT)
    return So101Arm(link.url, calibration=CAL, **kw)  # type: ignore[arg-type]


def retries_said(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if "trying again" in r.getMessage()]


# ---------------------------------------------------------------- the handshake
async def test_a_handshake_the_bus_does_not_answer_is_tried_again(
    link: BusLink, caplog: pytest.LogCaptureFixture
) -> None:
    """The servos answer nothing at first (an emulator off the CPU, servos powering
    up): the arm says so, waits, and connects once they answer, instead of ERROR."""
    mute_all(link, True)
    # The waits (1, 2, 4 s) leave a loaded machine time to unmute after the first.
    arm = arm_on(link, retry_delay_s=1.0)
    with caplog.at_level(logging.WARNING, logger=LOG):
        connecting = asyncio.create_task(arm.connect())
        await until_async(lambda: "attempt 1 of 4" in arm.status_message, timeout=20)
        assert "none of the 6 servos answers on" in arm.status_message
        assert "trying again in 1 s" in arm.status_message
        mute_all(link, False)
        await connecting
    assert arm.status is RobotStatus.CONNECTED
    said = retries_said(caplog)
    assert said and link.url in said[0] and "attempt 1 of 4" in said[0], said
    await arm.disconnect()


async def test_a_bus_that_never_answers_ends_in_error_after_its_tries(
    link: BusLink, caplog: pytest.LogCaptureFixture
) -> None:
    mute_all(link, True)
    # Nothing answers: a short reply timeout keeps the three tries short.
    arm = arm_on(link, connect_attempts=3, retry_delay_s=0.01, reply_timeout=0.02)
    with caplog.at_level(logging.WARNING, logger=LOG), pytest.raises(NoAnswer) as raised:
        await arm.connect()
    assert "none of the 6 servos answers on" in str(raised.value)
    assert "(tried 3 times)" in str(raised.value)
    assert arm.status is RobotStatus.ERROR and "tried 3 times" in arm.status_message
    assert len(retries_said(caplog)) == 2  # each failed try but the last, said
    assert arm._serial is None and arm._poller is None  # nothing left half open


async def test_an_arm_that_answers_wrong_is_not_tried_again(
    link: BusLink, caplog: pytest.LogCaptureFixture
) -> None:
    link.servo(5).memory[Register.MODEL_NUMBER : Register.MODEL_NUMBER + 2] = ft.le16(1284)
    arm = arm_on(link, retry_delay_s=5.0)  # a retry would show as a 5 s wait
    with caplog.at_level(logging.WARNING, logger=LOG), pytest.raises(DeviceError) as raised:
        await arm.connect()
    assert not isinstance(raised.value, NoAnswer) and "not an STS3215" in str(raised.value)
    assert retries_said(caplog) == []


# ---------------------------------------------------------------- the whole bus silent
async def test_a_bus_that_falls_silent_is_one_fault_that_says_so(link: BusLink) -> None:
    arm = arm_on(link)
    await arm.connect()
    await arm.initialize()
    mute_all(link, True)
    await until_async(lambda: arm.status is RobotStatus.ERROR, timeout=20)
    message = arm.status_message
    # One sentence for the bus, not six for six servos.
    assert "all 6 servos stopped answering on" in message, message
    assert "servo 1 (shoulder_pan) stopped answering" not in message
    mute_all(link, False)
    await arm.disconnect()


async def test_an_initialisation_the_bus_stalls_is_connected_and_tried_again(
    link: BusLink, caplog: pytest.LogCaptureFixture
) -> None:
    """Start-up as the server does it (connect, then initialise) with the bus falling
    silent in between: the arm connects again and initialises, rather than ERROR."""
    arm = arm_on(link, retry_delay_s=1.0)
    await arm.connect()
    mute_all(link, True)
    with caplog.at_level(logging.WARNING, logger=LOG):
        initialising = asyncio.create_task(arm.initialize())
        await until_async(lambda: "connecting again" in arm.status_message, timeout=20)
        assert arm.status is RobotStatus.ERROR  # while it waits: said, not hidden
        mute_all(link, False)
        await initialising
    assert arm.status is RobotStatus.READY
    np.testing.assert_allclose(arm.joints, MODEL.pose("ready"), atol=0.01)
    said = [r.getMessage() for r in caplog.records if "connecting again" in r.getMessage()]
    assert said and "attempt 1 of 4" in said[0], said
    await arm.disconnect()


async def test_one_servo_that_stops_answering_is_not_tried_again(link: BusLink) -> None:
    arm = arm_on(link, retry_delay_s=5.0)
    await arm.connect()
    await arm.initialize()
    link.servo(4).mute = True
    await until_async(lambda: arm.status is RobotStatus.ERROR, timeout=20)
    assert "servo 4 (wrist_flex) stopped answering" in arm.status_message
    link.servo(4).mute = False
    with pytest.raises(NotReady, match="connect it before initialising"):
        await arm.initialize()  # at once: no reconnecting behind the operator's back
    await arm.disconnect()


# ---------------------------------------------------------------- REST
def test_initialize_takes_an_empty_body(client: TestClient) -> None:
    r = client.post("/api/v1/lease", json={"name": "curl"}, headers=AUTH)
    assert r.status_code == 200, r.text
    headers = {**AUTH, "X-Client-Id": r.json()["client_id"]}
    r = client.post("/api/v1/robot/initialize", headers=headers)  # `curl -X POST`: no body
    assert r.status_code == 200, r.text
    assert r.json()["status"] == "READY"
    empty_json = {**headers, "Content-Type": "application/json"}
    assert client.post("/api/v1/robot/initialize", headers=empty_json).status_code == 200
    assert client.post("/api/v1/robot/initialize", json={}, headers=headers).status_code == 200
    # A body that is there is still checked.
    r = client.post("/api/v1/robot/initialize", json={"joints": [0.0]}, headers=headers)
    assert r.status_code == 422, r.text


# ---------------------------------------------------------------- the leader's wait
class FakeLink:
    joint_count = 6
    on_state: object = None
    on_reply: object = None


def test_a_leader_says_why_it_waits_for_an_arm_in_error() -> None:
    mir = JointMirror(SimLeader(MODEL), FakeLink(), MODEL.joint_names)  # type: ignore[arg-type]
    here = MODEL.pose("ready")

    def state(status: RobotStatus) -> None:
        mir._on_state(
            {"status": list(RobotStatus).index(status), "flags": 0, "joints": here.tolist()}
        )

    state(RobotStatus.ERROR)
    mir.step(here, here, at_rest=False)
    assert mir.status.startswith("the arm is in ERROR: it needs initialising"), mir.status
    assert "come to rest" not in mir.status
    why = "all 6 servos stopped answering on 'socket://127.0.0.1:7010'"
    mir._on_reply(Reply("EVENT", {"kind": int(m.EventKind.STATUS)}, f"ERROR: {why}"))
    mir.step(here, here, at_rest=False)
    assert f"the arm is in ERROR ({why})" in mir.status and "Home on the page" in mir.status
    state(RobotStatus.CONNECTED)
    mir.step(here, here, at_rest=False)
    assert mir.status.startswith("the arm is connected, not initialised"), mir.status
    assert why not in mir.status  # what was said of the ERROR is not said of this
    state(RobotStatus.MOVING)
    mir.step(here, here, at_rest=False)
    assert mir.status == "waiting for the arm to come to rest"
