"""What the LeRobot plugins are made of (``telerobot.client.lerobot``), without LeRobot:
LeRobot's units against its own formulas, then the arm and the operator against a real
server running the simulated SO-101 with its stereo video (the plugins themselves, in
LeRobot's own tools: integrations/lerobot/tests)."""

from __future__ import annotations

import logging
import math
import time

import httpx
import numpy as np
import pytest

from telerobot.client import Telerobot
from telerobot.client.lerobot.arm import ArmOptions, TelerobotArm
from telerobot.client.lerobot.cameras import capture_time
from telerobot.client.lerobot.operator import OperatorOptions, TelerobotOperator
from telerobot.client.lerobot.units import JointUnits
from telerobot.drivers.camera import timecode
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.calibration import STEPS_PER_RADIAN
from tests.support import TOKEN, until
from tests.support.servers import serving

SO101 = load_model("so101")
SO101_UNITS = JointUnits.of("so101", SO101.joint_names, SO101.qlim)
FORCES = ("fx", "fy", "fz", "tx", "ty", "tz")


def lerobot_degrees(steps: float, range_min: float, range_max: float) -> float:
    """LeRobot 0.6.1's MotorNormMode.DEGREES (motors_bus._normalize)."""
    mid = (range_min + range_max) / 2
    return (steps - mid) * 360 / 4095


def test_so101_joints_read_as_lerobots_so_follower_reads_them() -> None:
    """The calibration puts a joint's zero at the middle of LeRobot's range (its
    ``zero_steps``): the same servo position gives LeRobot's degrees exactly."""
    lo, hi = 1000.0, 3000.0  # a joint's calibrated range, in steps
    for steps in (1000.0, 1733.0, 2000.0, 2999.0):
        q = (steps - (lo + hi) / 2) / STEPS_PER_RADIAN  # the model's angle (direction +1)
        ours = SO101_UNITS.to_lerobot(np.array([q, 0, 0, 0, 0, SO101.qlim[5][0]]))[0]
        assert ours == pytest.approx(lerobot_degrees(steps, lo, hi), abs=1e-9)


def test_the_gripper_is_0_to_100_percent_of_its_range_and_units_go_back() -> None:
    lo, hi = SO101.qlim[5]
    q = np.array([0.1, -0.2, 0.3, -0.4, 0.5, lo])
    assert SO101_UNITS.to_lerobot(q)[5] == pytest.approx(0.0)
    q[5] = hi
    assert SO101_UNITS.to_lerobot(q)[5] == pytest.approx(100.0)
    q[5] = (lo + hi) / 2
    values = SO101_UNITS.to_lerobot(q)
    assert values[5] == pytest.approx(50.0)
    np.testing.assert_allclose(SO101_UNITS.from_lerobot(values), q, atol=1e-12)
    assert SO101_UNITS.robot_type == "so_follower"
    assert SO101_UNITS.feature_names[-1] == "gripper.pos"


def test_the_puma_is_in_plain_degrees() -> None:
    puma = load_model("puma560")
    units = JointUnits.of("puma560", puma.joint_names, puma.qlim)
    np.testing.assert_allclose(units.to_lerobot(np.full(6, math.pi / 2)), np.full(6, 90.0))
    assert units.robot_type == "puma560" and units.describe() == "degrees"


def test_a_target_beyond_the_limits_is_clipped_and_named() -> None:
    q = np.array(SO101.qlim)[:, 1] + 0.5
    clipped, moved = SO101_UNITS.clip(q)
    np.testing.assert_allclose(clipped, np.array(SO101.qlim)[:, 1])
    assert moved == list(SO101.joint_names)


def test_a_frames_capture_time_is_read_from_its_timecode() -> None:
    image = np.zeros((64, 640, 3), np.uint8)
    timecode.draw(image, 1234.5678)
    assert capture_time(timecode.read(image), 1234.6) == pytest.approx(1234.5678, abs=2e-4)
    assert capture_time(None, 1.0) is None


VIDEO = {
    "TELEROBOT_VIDEO": "true",
    "TELEROBOT_VIDEO_WIDTH": "640",  # (the timecode is 528 pixels wide)
    "TELEROBOT_VIDEO_HEIGHT": "360",
}


@pytest.fixture(scope="module")
def so101() -> str:
    with serving(VIDEO, "--model", "so101") as base:
        yield base


def _state(base: str) -> dict:
    return httpx.get(base + "api/v1/robot/state").json()


def test_the_arm_reads_moves_clips_and_gives_way_to_an_operator(so101: str) -> None:
    options = ArmOptions(url=so101, token=TOKEN, name="lerobot test", width=320, height=180)
    arm = TelerobotArm(options)
    with pytest.raises(ConnectionError, match="not connected"):
        arm.observation()
    arm.connect()
    operator = TelerobotOperator(OperatorOptions(so101, TOKEN, robot_client_name="lerobot test"))
    operator.connect()
    try:
        units = arm.only.units
        assert units is not None and units.names == SO101.joint_names
        obs = arm.observation()
        assert obs["left"].shape == obs["right"].shape == (180, 320, 3)
        # The joints and the cameras, as LeRobot's so_follower: the forces beside them.
        assert set(obs) == {*units.feature_names, "left", "right"}
        assert set(arm.force) == {"fx", "fy", "fz", "tx", "ty", "tz"}
        here = units.to_lerobot(_state(so101)["joints"])
        got = [obs[k] for k in units.feature_names]
        np.testing.assert_allclose(got, here, atol=0.5)  # the arm at rest: degrees
        assert arm.receiver is not None and arm.receiver.latest().capture_source == "timecode"
        assert arm.last_skew_s is not None and abs(arm.last_skew_s) < 1.0
        assert not operator.intervening()  # the arm's own client holds control

        # A move: shoulder_pan by 10°, through the server.
        target = dict(zip(units.feature_names, got, strict=True))
        target["shoulder_pan.pos"] += 10.0
        applied = arm.send(target)
        assert applied["shoulder_pan.pos"] == pytest.approx(target["shoulder_pan.pos"])
        until(
            lambda: abs(arm.observation()["shoulder_pan.pos"] - target["shoulder_pan.pos"]) < 1,
            timeout=30,
            what=lambda: f"shoulder_pan at {arm.observation()['shoulder_pan.pos']}",
        )
        assert operator.action()["shoulder_pan.pos"] == pytest.approx(
            target["shoulder_pan.pos"], abs=0.5
        )

        # Beyond its limit: clipped to it, said and counted.
        beyond = dict(target, **{"elbow_flex.pos": 1000.0})
        applied = arm.send(beyond)
        upper = math.degrees(SO101.qlim[2][1]) * 4096 / 4095  # LeRobot's degrees
        assert applied["elbow_flex.pos"] == pytest.approx(upper)
        assert arm.clipped == 1
        with pytest.raises(ValueError, match=r"no wrist_roll\.pos"):
            arm.send({k: v for k, v in target.items() if k != "wrist_roll.pos"})
        with pytest.raises(ValueError, match="not finite"):
            arm.send(dict(target, **{"gripper.pos": float("nan")}))

        # An operator takes over: the arm's actions are no longer sent, what it returns
        # is the server's target, and the operator is intervening.
        with Telerobot(so101, TOKEN, name="operator", take_over=True) as person:
            until(lambda: operator.intervening(), timeout=10, what="the operator's control")
            until(lambda: not arm.has_control, timeout=10, what="the lease taken")
            person.move_joints([0.0] * 6)
            pan_before = _state(so101)["target_joints"][0]
            returned = arm.send(dict(target, **{"shoulder_pan.pos": 40.0}))
            time.sleep(0.3)
            assert _state(so101)["target_joints"][0] == pytest.approx(pan_before)
            assert returned == pytest.approx(operator.action(), abs=1e-6)
            time.sleep(1.2)  # past the take-back's spacing: it still takes nothing held
            arm.send(target)
            time.sleep(0.3)
            assert not arm.has_control and operator.intervening()

        # The operator lets go: the lease is free, and the arm takes it back at its next
        # actions (lerobot-record goes on recording LeRobot's actions, not nobody's).
        def sent_and_holds() -> bool:
            arm.send(target)
            return arm.has_control

        until(sent_and_holds, timeout=15, what="the arm taking the free lease back")
        until(lambda: not operator.intervening(), timeout=10, what="the arm driving again")
    finally:
        operator.disconnect()
        arm.disconnect()
    assert not arm.connected


def test_without_the_operator_token_the_arm_is_refused(so101: str) -> None:
    arm = TelerobotArm(ArmOptions(url=so101, token="", cameras=False))
    with pytest.raises(PermissionError, match="operator token"):
        arm.connect()
    assert not arm.connected


def test_an_unreachable_server_is_said() -> None:
    arm = TelerobotArm(ArmOptions(url="http://127.0.0.1:9/", token=TOKEN, cameras=False))
    with pytest.raises(ConnectionError, match=r"cannot ask http://127\.0\.0\.1:9/ for its arm"):
        arm.connect()


def test_a_picture_without_a_timecode_is_dated_by_its_arrival() -> None:
    """A real camera's corner reads as some number: a time minutes away is no timecode."""
    image = np.zeros((64, 640, 3), np.uint8)
    timecode.draw(image, 1000.0)
    assert capture_time(timecode.read(image), 1300.0) is None


def test_a_server_with_two_arms_is_one_robot_of_both_left_first() -> None:
    """A two-arm server is one robot of both, as LeRobot's bimanual robots are: every
    key prefixed with its arm's name, two SO-101s named left and right in
    ``bi_so_follower``'s order (left first) though the server lists right first; each
    arm moves by its own keys alone. The teleoperator has the same shape (LeRobot's
    ``bi_so_leader``): its action is each arm's target, under the same keys."""
    from telerobot.client.lerobot.arm import robot_type

    two_arms = {"TELEROBOT_ARMS": "right=so101:sim,left=so101:sim"}
    with serving(two_arms) as base:
        arm = TelerobotArm(ArmOptions(url=base, token=TOKEN, name="bimanual", cameras=False))
        arm.connect()
        operator = TelerobotOperator(OperatorOptions(base, TOKEN, robot_client_name="bimanual"))
        operator.connect()
        try:
            assert [p.name for p in arm.parts] == ["left", "right"]
            assert robot_type(arm.parts) == "bi_so_follower"
            keys = [f"{side}_{j}.pos" for side in ("left", "right") for j in SO101.joint_names]
            assert arm.keys == keys
            with pytest.raises(ValueError, match="2 arms"):
                arm.only  # noqa: B018 (a one-arm caller is told)
            here = arm.observation()
            assert list(here) == keys
            assert set(arm.force) == {f"{s}_{f}" for s in ("left", "right") for f in FORCES}
            moved = dict(here, **{"right_shoulder_pan.pos": here["right_shoulder_pan.pos"] + 10})
            applied = arm.send(moved)  # far from the arm: reached before send returns
            assert applied == pytest.approx(moved, abs=1e-6)
            now = arm.observation()
            assert now["right_shoulder_pan.pos"] == pytest.approx(
                moved["right_shoulder_pan.pos"], abs=1.0
            )
            left = [k for k in keys if k.startswith("left_")]
            assert [now[k] for k in left] == pytest.approx([here[k] for k in left], abs=0.1)
            with pytest.raises(ValueError, match=r"right_gripper\.pos"):
                arm.send({k: v for k, v in moved.items() if k != "right_gripper.pos"})
            assert operator.keys == keys
            assert operator.action() == pytest.approx(moved, abs=1e-6)  # the arms' targets
            assert not operator.intervening()  # the robot's own client drives
        finally:
            operator.disconnect()
            arm.disconnect()


def test_at_connect_the_robot_says_the_rate_its_frames_can_keep(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Read at 30 fps from a server whose cameras give 10, the robot says so at connect,
    with the rate to record at (else lerobot-record's frames repeat unsaid)."""
    slow = {**VIDEO, "TELEROBOT_VIDEO_FPS": "10"}
    with serving(slow, "--model", "so101") as base:
        arm = TelerobotArm(ArmOptions(url=base, token=TOKEN, width=160, height=90, fps=30))
        with caplog.at_level(logging.WARNING, logger="telerobot.client.lerobot.arm"):
            arm.connect()
        arm.disconnect()
    said = [r.getMessage() for r in caplog.records if "--dataset.fps=" in r.getMessage()]
    assert len(said) == 1 and "(the server's cameras: 10 fps)" in said[0], caplog.text
    assert arm.video_rate_hz is not None and arm.video_rate_hz <= 11


def test_a_joint_at_its_limit_read_back_from_float32_is_not_a_clip() -> None:
    """A dataset stores joints as float32: a joint recorded at its limit reads back a hair
    beyond it. That is held at the limit unsaid; a target truly beyond is still said."""
    units = SO101_UNITS
    at_limits = np.array([hi for _, hi in units.limits])
    stored = units.to_lerobot(at_limits).astype(np.float32)
    back, moved = units.clip(units.from_lerobot(stored))
    assert moved == []
    np.testing.assert_allclose(back, at_limits, atol=1e-6)
    beyond = at_limits.copy()
    beyond[0] += 0.01
    assert units.clip(beyond)[1] == [units.names[0]]


def test_a_first_action_far_from_the_arm_is_reached_before_send_returns() -> None:
    """A replay's (or a rollout's) first action, far from where the arm is, is reached
    before ``send`` returns: lerobot-replay times each frame after the last returns, so
    its clock starts with the arm at the episode's first pose. The actions that follow
    (within a second) return at once, the arm following them."""
    with serving({}, "--model", "so101") as so101:  # its own arm: at rest, in free space
        _replays_first_action(so101)


def _replays_first_action(so101: str) -> None:
    arm = TelerobotArm(ArmOptions(url=so101, token=TOKEN, name="replayer", cameras=False))
    arm.connect()
    try:
        units = arm.only.units
        assert units is not None
        here = arm.observation()
        far = dict(here, **{"shoulder_pan.pos": here["shoulder_pan.pos"] + 30.0})  # 0.52 rad
        arm.send(far)
        reached = units.from_lerobot([arm.observation()[k] for k in units.feature_names])
        wanted = units.from_lerobot([far[k] for k in units.feature_names])
        assert np.abs(reached - wanted).max() < 0.02  # there when send returned
        back = dict(far, **{"shoulder_pan.pos": here["shoulder_pan.pos"]})
        arm.send(back)  # the next frame: not waited for
        pan = arm.observation()["shoulder_pan.pos"]
        assert abs(pan - back["shoulder_pan.pos"]) > 20.0  # still on its way
    finally:
        arm.disconnect()
