"""The joint mirror (a leader arm driving the follower joint for joint through the
server): its rule in isolation, then a scripted leader against a real server
running the simulated SO-101 over the priority channel."""

from __future__ import annotations

import math
import subprocess
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from telerobot.client.master.cli import open_link
from telerobot.client.master.joints import MAX_IN_FLIGHT, JointMirror, MirrorSettings
from telerobot.client.master.link import Reply
from telerobot.drivers.base import FloatArray, InvalidCommand
from telerobot.drivers.master.sim_leader import SimLeader
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.calibration import JointCalibration, So101Calibration
from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator
from telerobot.drivers.robot.so101.leader import So101Leader
from telerobot.protocol import messages as m
from tests.support import TOKEN, until
from tests.support.servers import BIN, serving, telerobot

SO101 = load_model("so101")


class FakeLink:
    """What the mirror reads of a link, for the rule alone (no sending)."""

    joint_count = 6
    on_state: Any = None
    on_reply: Any = None


def mirror(**settings: float) -> JointMirror:
    return JointMirror(
        SimLeader(SO101),
        FakeLink(),  # type: ignore[arg-type]
        SO101.joint_names,
        MirrorSettings(**settings),
    )


def test_nothing_moves_until_the_leader_is_aligned_and_the_status_says_which_joint() -> None:
    mir = mirror(align_rad=0.15)
    follower = SO101.pose("ready")
    leader = follower.copy()
    leader[2] += 0.5
    assert mir.step(leader, None) is None and "waiting" in mir.status
    assert mir.step(follower, follower, at_rest=False) is None  # aligned, but moving
    assert mir.status == "waiting for the arm to come to rest"
    assert mir.step(leader, follower) is None
    assert mir.status == "align the leader: elbow_flex is +29° from the arm's"
    assert not mir.following
    leader[2] = follower[2] + 0.1  # within 0.15 rad: it follows
    dq = mir.step(leader, follower)
    assert mir.following and dq is not None and dq[2] > 0


def test_following_goes_at_most_the_speed_cap_and_converges_on_the_leader() -> None:
    mir = mirror(rate_hz=100.0, max_speed_rad_s=0.9, align_rad=0.2)
    follower = SO101.pose("ready")
    leader = follower + np.array([0.15, -0.1, 0.0, 0.05, 0.0, 0.2])
    commanded = follower.copy()
    steps = 0
    while (dq := mir.step(leader, follower)) is not None:
        assert np.abs(dq).max() <= 0.009 + 1e-12  # 0.9 rad/s at 100 Hz
        commanded += dq
        steps += 1
    assert steps == math.ceil(0.2 / 0.009)  # the gripper's 0.2 rad at the cap
    assert np.allclose(commanded, leader, atol=1e-12)
    assert "lag 0.0°" in mir.status


def test_a_scaled_or_refused_increment_is_taken_back_from_the_record() -> None:
    mir = mirror(align_rad=0.2, rate_hz=100.0, max_speed_rad_s=0.9)
    follower = SO101.pose("ready")
    leader = follower + 0.1
    first = mir.step(leader, follower)
    second = mir.step(leader, follower)
    assert first is not None and second is not None
    mir._sent = {7: first, 8: second}
    limited = {"result": m.Ack.LIMITED, "server_time": 1.0}
    mir._on_reply(Reply("ACK", {"seq": 7, **limited, "scale": 0.25}, ""))
    mir._on_reply(Reply("ERROR", {"seq": 8, "code": 6}, "refused"))
    mir._on_reply(Reply("ACK", {"seq": 99, **limited, "scale": 0.5}, ""))  # not ours
    third = mir.step(leader, follower)
    assert third is not None and (mir.scaled, mir.refused) == (1, 1)
    # The record is what the server applied: a quarter of the first, none of the second.
    applied = follower + 0.25 * first + third
    assert np.allclose(mir._commanded, applied)  # type: ignore[arg-type]


def test_replies_that_never_come_make_it_align_again_rather_than_grow() -> None:
    class Sending(FakeLink):
        seq = 0

        def next_seq(self) -> int:
            self.seq += 1
            return self.seq

        def joints(self, dq: list[float], seq: int, arm: int | str = 0) -> int:
            return seq

    mir = JointMirror(SimLeader(SO101), Sending(), SO101.joint_names)  # type: ignore[arg-type]
    mir.flags = m.StateFlags.YOU_HAVE_CONTROL
    mir._follower = SO101.pose("ready") - 0.05  # the sim leader rests at ready: aligned
    for _ in range(MAX_IN_FLIGHT + 1):
        mir._commanded = mir._follower.copy()  # always something to send
        mir.tick()
    assert len(mir._sent) == 0 and not mir.following  # cleared at the bound


def test_an_arm_stopped_by_the_server_is_aligned_again() -> None:
    mir = mirror(align_rad=0.15)
    follower = SO101.pose("ready")
    leader = follower + 0.1
    mir._sent = {3: np.full(6, 0.01)}
    assert mir.step(leader, follower) is not None and mir.following
    # The dead-man stopped it short: at rest, away from the record.
    assert mir.step(leader, follower - 0.3, at_rest=True) is None
    assert not mir.following and mir._sent == {}
    assert mir.status.startswith("align the leader")


def test_increments_still_on_their_way_are_no_stop() -> None:
    """A loaded server answers late: the arm rests where the applied increments took
    it while more are on their way. That is not the server stopping it (a run with one
    core busy saw the mirror give up following there)."""
    mir = mirror(align_rad=0.15, rate_hz=100.0, max_speed_rad_s=0.9)
    follower = SO101.pose("ready")
    assert mir.step(follower + 0.1, follower) is not None  # aligned: following
    leader = follower + 0.3
    mir._commanded = follower + 0.25  # (as after many increments)
    mir._sent = {k: np.full(6, 0.25 / 20) for k in range(20)}  # all unanswered yet
    assert mir.step(leader, follower, at_rest=True) is not None
    assert mir.following and mir.status.startswith("following")


def test_a_leader_of_another_arm_is_refused() -> None:
    with pytest.raises(InvalidCommand, match="not the arm's"):
        JointMirror(SimLeader(SO101), FakeLink(), load_model("puma560").joint_names)  # type: ignore[arg-type]
    with pytest.raises(InvalidCommand, match="must be a positive number"):
        MirrorSettings(align_rad=math.nan).check()


def test_a_scripted_leader_drives_the_simulated_so101_through_the_server() -> None:
    home = SO101.pose("ready")
    target = home + np.array([0.3, 0.0, -0.2, 0.0, 0.4, 0.3])
    # The hand's script goes step by step when the test says, not on the wall clock:
    # a busy machine must not find it a step further than the test thinks.
    step = ["off"]

    def hand(t: float) -> FloatArray:
        if step[0] == "off":  # held 0.6 rad off at the wrist: the arm must not follow
            return home + np.array([0.0, 0.0, 0.0, 0.6, 0.0, 0.0])
        return target if step[0] == "target" else home

    env = {
        "TELEROBOT_OPERATOR_TOKEN": TOKEN,
        "TELEROBOT_ROBOT_MODEL": "so101",
        "TELEROBOT_PRIORITY_PORT": "0",
        "TELEROBOT_VIEWER": "false",
    }
    with serving(env) as base:
        link = open_link(base, TOKEN, datagrams=False)
        mir = JointMirror(SimLeader(SO101, hand), link, SO101.joint_names)
        mir.start()
        try:

            def target_joints() -> np.ndarray:
                return np.array(httpx.get(base + "api/v1/robot/state").json()["target_joints"])

            until(lambda: "align the leader: wrist_flex" in mir.status, what=lambda: mir.status)
            time.sleep(0.5)  # the chance to go wrong
            assert "align the leader: wrist_flex" in mir.status, mir.status
            assert np.allclose(target_joints(), home, atol=1e-6), "moved before aligned"
            assert mir.commands_sent == 0
            step[0] = "home"  # aligned: it follows, and the arm stays where it is
            until(lambda: mir.following, what=lambda: mir.status)
            assert np.allclose(target_joints(), home, atol=1e-3)
            step[0] = "target"
            until(
                lambda: np.abs(target_joints() - target).max() <= 1e-3,
                what=lambda: f"{mir.status}, {mir.last_error}, {target_joints()}",
            )
            # (A command the server found stale, held up past the dead-man on a loaded
            # machine, is dropped and said; the mirror carries on.)
            error = mir.last_error
            assert mir.commands_sent > 0 and (error is None or "stale command" in error), error
        finally:
            mir.stop()
            link.close()


# ---------------------------------------------------------------- the SO-101 leader
# Each arm assembled its own way: the leader's and the follower's zeros differ.
FOLLOWER_CAL = So101Calibration(
    SO101.joint_names,
    tuple(
        JointCalibration(i + 1, zero, d)
        for i, (zero, d) in enumerate(
            [(2048.0, 1), (2100.0, -1), (1990.0, 1), (2050.0, 1), (2048.0, -1), (1900.0, 1)]
        )
    ),
)
LEADER_CAL = So101Calibration(
    SO101.joint_names,
    tuple(
        JointCalibration(i + 1, zero, d)
        for i, (zero, d) in enumerate(
            [(2000.0, -1), (2048.0, 1), (2150.0, 1), (1980.0, -1), (2048.0, 1), (2200.0, -1)]
        )
    ),
)


def emulated(cal: So101Calibration, pose: FloatArray) -> FeetechBusEmulator:
    steps = dict(zip(cal.ids, map(float, cal.to_steps(pose)), strict=True))
    return FeetechBusEmulator(start=steps)


def test_the_so101_leader_drives_the_so101_follower_through_the_server(tmp_path: Path) -> None:
    """Leader bus emulator → So101Leader → the mirror → the server → So101Arm →
    follower bus emulator: every byte real, over TCP."""
    ready = SO101.pose("ready")
    follower_cal = tmp_path / "follower.json"
    FOLLOWER_CAL.save(follower_cal)
    with (
        BusLink.on_tcp(emulated(FOLLOWER_CAL, SO101.pose("rest"))) as follower_bus,
        BusLink.on_tcp(emulated(LEADER_CAL, ready)) as leader_bus,
    ):
        env = {
            "TELEROBOT_OPERATOR_TOKEN": TOKEN,
            "TELEROBOT_ROBOT": "so101",
            "TELEROBOT_ROBOT_MODEL": "so101",
            "TELEROBOT_SO101_PORT": follower_bus.url,
            # The emulated bus is a thread behind a pty: on a loaded machine it can
            # take longer than a real servo's 30 ms to answer.
            "TELEROBOT_SO101_REPLY_TIMEOUT": "0.25",
            "TELEROBOT_SO101_CALIBRATION": str(follower_cal),
            "TELEROBOT_PRIORITY_PORT": "0",
            "TELEROBOT_VIEWER": "false",
        }
        with serving(env) as base:  # initialised: the follower at "ready"

            def follower() -> np.ndarray:
                return np.array(httpx.get(base + "api/v1/robot/state").json()["joints"])

            assert np.abs(follower() - ready).max() < 0.01
            link = open_link(base, TOKEN, datagrams=False)
            # A servo has 0.25 s to answer, not the driver's 20 ms: the emulator is a thread
            # here, kept off the CPU for longer on a loaded machine.
            leader = So101Leader(leader_bus.url, LEADER_CAL, reply_timeout=0.25)
            mir = JointMirror(leader, link, SO101.joint_names)
            mir.start()
            try:
                assert not any(leader_bus.servo(i).torque for i in LEADER_CAL.ids)
                deadline = time.monotonic() + 5
                while not mir.following:  # in control, the leader where the arm is
                    assert time.monotonic() < deadline, mir.status
                    time.sleep(0.05)
                # The operator moves the leader by hand (its servos, torque off).
                moved = ready + np.array([0.25, -0.15, 0.2, -0.1, 0.3, 0.2])
                for i, steps in zip(LEADER_CAL.ids, LEADER_CAL.to_steps(moved), strict=True):
                    leader_bus.servo(i).position = float(steps)
                deadline = time.monotonic() + 10
                while np.abs(follower() - moved).max() > 0.01:
                    assert time.monotonic() < deadline, (mir.status, mir.last_error, follower())
                    time.sleep(0.1)
                # Its elbow servo goes quiet: the mirror says which and stops sending.
                leader_bus.servo(3).mute = True
                deadline = time.monotonic() + 5
                while mir.last_error is None:
                    assert time.monotonic() < deadline, mir.status
                    time.sleep(0.05)
                assert "servo 3 (elbow_flex) stopped answering" in mir.last_error
                sent = mir.commands_sent
                time.sleep(0.3)
                assert mir.commands_sent == sent
            finally:
                mir.stop()
                link.close()


def test_the_master_command_mirrors_a_leader_and_says_so() -> None:
    env = {"TELEROBOT_ROBOT_MODEL": "so101", "TELEROBOT_VIEWER": "false"}
    with (
        serving(env, ready=False) as base,
        telerobot(
            "master", "--server", base, "--token", TOKEN, "--device", "sim-leader",
            wait_for=r"Leader sim-leader mirrored onto the SO-101 .* as operator",
        ),
    ):  # fmt: skip
        home = SO101.pose("ready")
        deadline = time.monotonic() + 10
        # The scripted leader sways the first joint: the arm follows it.
        while abs(httpx.get(base + "api/v1/robot/state").json()["target_joints"][0]) < 0.05:
            assert time.monotonic() < deadline
            time.sleep(0.1)
        assert httpx.get(base + "api/v1/robot/state").json()["target_joints"][1] == (
            pytest.approx(home[1], abs=1e-6)
        )
        # Who has control is the bridge's own name (NAME), not "priority 127.0.0.1:…".
        assert httpx.get(base + "api/v1/safety").json()["controller"] == "master sim-leader"

    def master_to_nowhere(*args: str) -> subprocess.CompletedProcess[str]:
        command = [str(BIN), "master", "--server", "http://127.0.0.1:9/", *args]
        return subprocess.run(command, capture_output=True, text=True, timeout=60)

    bad = master_to_nowhere("--name", "me (again)")
    assert bad.returncode == 2 and "--name: a name is 1–64 characters" in bad.stderr
    out = master_to_nowhere("--device", "so101-leader")
    assert out.returncode == 1 and "cannot ask http://127.0.0.1:9/ for its arm" in out.stderr
