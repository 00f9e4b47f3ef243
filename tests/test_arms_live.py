"""Two arms through a real server (docs/arms.md): two simulated SO-101s driven at once
over /ws and over REST, the e-stop stops both, a one-arm client is refused with the
arms' names, and a fault on the right arm (the real SO-101 driver on an emulated servo
bus whose servo stops answering) stops that arm only, in a message that names it."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from websockets.sync.client import connect

from telerobot.client import Telerobot
from telerobot.client.master.cli import open_link
from telerobot.client.rest import TelerobotError
from telerobot.drivers.base import ForceSample
from telerobot.drivers.robot.so101.emulator import BusLink
from telerobot.protocol import messages as m
from tests.support import TOKEN, until
from tests.support.browser import NO_VIDEO
from tests.support.servers import serving
from tests.support.so101_bus import FOLLOWER_CAL, SO101, emulated

TWO_SIM_ARMS = {**NO_VIDEO, "TELEROBOT_ARMS": "left=so101:sim,right=so101:sim"}
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture(scope="module")
def server() -> Iterator[str]:
    with serving(TWO_SIM_ARMS) as base:
        yield base


def position(base: str, arm: str) -> np.ndarray:
    state = httpx.get(base + "api/v1/robot/state", params={"arm": arm}).json()
    assert state["arm"] == arm
    return np.array(state["position"])


def status(base: str, arm: str) -> str:
    return str(httpx.get(base + "api/v1/robot/state", params={"arm": arm}).json()["status"])


def ws_url(base: str) -> str:
    return base.replace("http", "ws", 1) + "ws?name=bimanual"


def replies(ws, until_seq: int) -> dict[int, tuple[str, str]]:  # type: ignore[no-untyped-def]
    """ACK or ERROR (and its text) for every command up to ``until_seq``."""
    got: dict[int, tuple[str, str]] = {}
    while until_seq not in got:
        msg, f, text = m.decode(ws.recv(timeout=10))
        if msg in (m.ACK, m.ERROR):
            got[int(f["seq"])] = (msg.name, text)
    return got


def test_the_arms_are_listed_and_welcome_says_them(server: str) -> None:
    arms = httpx.get(server + "api/v1/robot/arms").json()
    assert [(a["name"], a["index"], a["dof"]) for a in arms] == [("left", 1, 6), ("right", 2, 6)]
    right_base = np.array(arms[1]["mount"])
    assert right_base[0, 3] > 0.3 and right_base[0, 0] == pytest.approx(-1)  # across, facing
    with connect(ws_url(server), origin=server.rstrip("/")) as ws:
        ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
        welcome = m.decode(ws.recv(timeout=10))
        assert welcome[0] is m.WELCOME and welcome[1]["arms"] == 2
        listed = [m.decode(ws.recv(timeout=10)) for _ in range(2)]
        assert [(f["index"], f["joints"], text) for _, f, text in listed] == [
            (1, 6, "left"),
            (2, 6, "right"),
        ]
        states: set[int] = set()
        forces: set[int] = set()
        while len(states) < 2 or len(forces) < 2:
            msg, f, _ = m.decode(ws.recv(timeout=10))
            (states if msg is m.STATE else forces if msg is m.FORCE else set()).add(f.get("arm"))
        assert states == forces == {1, 2}


def test_both_arms_driven_at_once_over_ws_and_a_one_arm_command_is_refused(server: str) -> None:
    start = {arm: position(server, arm) for arm in ("left", "right")}
    with connect(ws_url(server), origin=server.rstrip("/")) as ws:
        ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, TOKEN.encode()))
        ws.send(m.encode(m.LEASE, 1, m.LeaseAction.TAKE))
        seq = 1
        for _ in range(30):  # both arms up, 2 mm a command each, interleaved
            for arm in (1, 2):
                seq += 1
                now = time.monotonic()  # our own clock: only a wait on the way is judged
                ws.send(m.encode(m.CART_INC, seq, now, m.Frame.BASE, 0, 0, 0.002, 0, 0, 0, arm))
            time.sleep(0.01)
        seq += 1
        now = time.monotonic()
        ws.send(m.encode(m.CART_INC, seq, now, m.Frame.BASE, 0, 0, 0.002, 0, 0, 0))  # arm 0
        got = replies(ws, seq)
        assert got[seq] == ("ERROR", got[seq][1]) and "drives 2 arms (left, right)" in got[seq][1]
        assert all(got[s][0] == "ACK" for s in range(2, seq)), [
            v for v in got.values() if v[0] != "ACK"
        ]
        ws.send(m.encode(m.LEASE, seq + 1, m.LeaseAction.RELEASE))
        replies(ws, seq + 1)
    until(lambda: status(server, "left") == status(server, "right") == "READY")
    for arm in ("left", "right"):
        rose = position(server, arm)[2] - start[arm][2]
        assert rose > 0.02, (arm, rose)  # most of 30 × 2 mm


def test_rest_and_the_python_client_name_the_arm_and_refuse_without(server: str) -> None:
    r = httpx.get(server + "api/v1/robot/state")
    assert r.status_code == 422 and "drives 2 arms (left, right)" in r.json()["detail"]
    with Telerobot(server, TOKEN, name="two-arm script") as robot:
        assert [a["name"] for a in robot.arms()] == ["left", "right"]
        with pytest.raises(TelerobotError, match=r"drives 2 arms \(left, right\)"):
            robot.move_cartesian([0.0, 0.0, 0.01], relative=True)
        before = {arm: position(server, arm) for arm in ("left", "right")}
        up = np.array([0.0, 0.0, 0.02])
        robot.arm("left").move_cartesian((before["left"] + up).tolist())
        assert position(server, "left") == pytest.approx(before["left"] + up, abs=0.002)
        assert np.abs(position(server, "right") - before["right"]).max() < 0.002
        robot.arm("right").move_cartesian((before["right"] - up).tolist())
        assert position(server, "right") == pytest.approx(before["right"] - up, abs=0.002)
        assert robot.arm("right").state()["arm"] == "right"


def test_the_e_stop_stops_both_arms(server: str) -> None:
    with Telerobot(server, TOKEN, name="e-stop script") as robot:
        homes = {a: np.array(robot.arm(a).state()["joints"]) for a in ("left", "right")}
        for arm, sign in (("left", 1), ("right", -1)):  # a long move each, not waited for
            robot.arm(arm).move_joints(
                homes[arm] + sign * np.array([0.6, 0, 0, 0, 0, 0]), wait=False
            )
        until(lambda: status(server, "left") == status(server, "right") == "MOVING")
        robot.estop()
        # Each arm brakes to a stop (its own deceleration: read at the e-stop, a quiet
        # run saw one still 0.058 rad on its way) and stays there.
        until(lambda: "MOVING" not in (status(server, "left"), status(server, "right")))
        stopped = {a: np.array(robot.arm(a).state()["joints"]) for a in ("left", "right")}
        time.sleep(0.3)
        for arm in ("left", "right"):
            assert status(server, arm) != "MOVING"
            assert np.abs(np.array(robot.arm(arm).state()["joints"]) - stopped[arm]).max() < 0.01
            with pytest.raises(TelerobotError, match="e-stop"):
                robot.arm(arm).move_joints(homes[arm])
        httpx.post(
            server + "api/v1/safety/reset", headers={**AUTH, "X-Client-Id": robot.client_id or ""}
        ).raise_for_status()


def test_a_fault_on_the_right_arm_stops_it_alone_and_says_which(tmp_path: Path) -> None:
    cal = tmp_path / "right.json"
    FOLLOWER_CAL.save(cal)
    ready = SO101.pose("ready")
    with BusLink.on_tcp(emulated(FOLLOWER_CAL, ready)) as bus:
        right = {
            "robot_model": "so101",
            "robot": "so101",
            "so101_port": bus.url,
            "so101_calibration": str(cal),
            # A thread behind a socket here: slower to answer than a real servo.
            "so101_reply_timeout": 0.25,
        }
        arms = {"left": {"robot_model": "so101", "robot": "sim"}, "right": right}
        with serving({**NO_VIDEO, "TELEROBOT_ARMS": json.dumps(arms)}) as base:
            with connect(ws_url(base), origin=base.rstrip("/")) as ws:
                ws.send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, b""))
                bus.servo(3).mute = True  # the right elbow's servo stops answering
                until(lambda: status(base, "right") == "ERROR", timeout=15)
                events = []
                while not any(t.startswith("right: ERROR") for t in events):
                    msg, _, text = m.decode(ws.recv(timeout=10))
                    if msg is m.EVENT:
                        events.append(text)
            assert status(base, "left") == "READY"
            with Telerobot(base, TOKEN) as robot:
                robot.arm("left").move_cartesian([0.0, 0.0, 0.005], relative=True)
                with pytest.raises(TelerobotError, match=r"^right: robot is ERROR"):
                    robot.arm("right").move_cartesian([0.0, 0.0, 0.01], relative=True)


def test_both_arms_forces_come_as_datagrams_none_held_back_by_the_rate(server: str) -> None:
    """A client's datagram budget is every arm's sensors' rate together (sized for one,
    the server dropped half of two arms' samples as over the rate)."""
    got: dict[int, int] = {1: 0, 2: 0}

    def on_arm_force(arm: int, sample: ForceSample, received: float) -> None:
        got[arm] += 1

    link = open_link(server, TOKEN, datagrams=True)
    link.on_arm_force = on_arm_force
    try:
        until(lambda: link.datagrams == "udp", what=lambda: link.datagrams)
        start = dict(got)
        time.sleep(1.5)
        counts = {arm: got[arm] - start[arm] for arm in got}
        assert min(counts.values()) > 0.7 * max(counts.values()), counts
        channel = httpx.get(server + "api/v1/force/channel").json()
        assert channel["limits"]["datagrams_over_rate"] == 0, channel
    finally:
        link.close()


async def test_each_arm_says_it_is_ready_by_its_name(caplog: pytest.LogCaptureFixture) -> None:
    """Two arms of one model have one robot name: 'robot sim-so101 is READY' came twice,
    saying nothing of which arm. Each says its arm; a one-arm server as before."""
    import logging
    from types import SimpleNamespace

    from telerobot.server.services import bring_up_robot

    async def nothing() -> None:
        return None

    robot: Any = SimpleNamespace(
        name="sim-so101", status="READY", connect=nothing, initialize=nothing
    )
    with caplog.at_level(logging.INFO, logger="telerobot"):
        await bring_up_robot(robot, True, "left")
        await bring_up_robot(robot, True, "right")
        await bring_up_robot(robot, True)
    said = [r.getMessage() for r in caplog.records if "READY" in r.getMessage()]
    assert said == [
        "arm left (robot sim-so101) is READY",
        "arm right (robot sim-so101) is READY",
        "robot sim-so101 is READY",
    ]
