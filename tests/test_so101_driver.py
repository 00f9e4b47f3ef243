"""So101Arm against the emulated Feetech bus over a real pseudo-terminal and a real
TCP socket, real threads (docs/architecture.md, rule 4), and its calibration."""

from __future__ import annotations

import asyncio
import functools
import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from telerobot.drivers.base import (
    DeviceError,
    InvalidCommand,
    NotReady,
    Robot,
    RobotStatus,
    StopCategory,
)
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.bus import MissCounter
from telerobot.drivers.motors.feetech.protocol import ErrorBit, Register
from telerobot.drivers.registry import load_driver
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.arm import (
    CALIBRATION_FILE,
    SETTLE_READS,
    So101Arm,
)
from telerobot.drivers.robot.so101.calibration import (
    STEPS_PER_RADIAN,
    CalibrationRecorder,
    JointCalibration,
    So101Calibration,
    from_lerobot,
)
from telerobot.drivers.robot.so101.emulator import BusLink, FeetechBusEmulator
from telerobot.server.devices import build_robot, describe_robot
from telerobot.server.settings import Settings
from tests.support import until_async as until

MODEL = load_model("so101")
NAMES = MODEL.joint_names
# The arm as assembled: each servo's mid-scale near the joint's zero, some mounted
# the other way round.
TRUE_CAL = So101Calibration(
    NAMES,
    tuple(
        JointCalibration(i + 1, zero, d)
        for i, (zero, d) in enumerate(
            [(2048.0, 1), (2100.0, -1), (1990.0, 1), (2050.0, 1), (2048.0, -1), (1900.0, 1)]
        )
    ),
)
STEP_RAD = 1 / STEPS_PER_RADIAN  # one step, radians


def start_steps(pose: str = "rest") -> dict[int, float]:
    return dict(zip(TRUE_CAL.ids, map(float, TRUE_CAL.to_steps(MODEL.pose(pose))), strict=True))


def wait_until(condition: Callable[[], bool], timeout: float = 5.0) -> None:
    """Block until ``condition`` holds (the poller thread and the emulator are real)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError("timed out")
        time.sleep(0.002)


@pytest.fixture(params=["pty", "tcp"])
def link(request: pytest.FixtureRequest) -> Iterator[BusLink]:
    bus = FeetechBusEmulator(start=start_steps())
    make = BusLink.on_pty if request.param == "pty" else BusLink.on_tcp
    with make(bus) as running:
        yield running


# How long a servo has to answer in these tests. The driver's 30 ms is for a real bus
# (a servo answers within a millisecond); here the emulator is a thread of this process,
# and on a loaded machine it can be kept off the CPU longer than that, which reads as a
# silent servo. The tests of a silent servo set their own, shorter one.
REPLY_TIMEOUT = 1.0
SILENT = 0.25  # a muted servo: long enough for the others on a loaded machine


def arm_on(link: BusLink, **kw: object) -> So101Arm:
    kw.setdefault("calibration", TRUE_CAL)
    kw.setdefault("reply_timeout", REPLY_TIMEOUT)
    return So101Arm(link.url, **kw)  # type: ignore[arg-type]


async def ready_arm(link: BusLink, **kw: object) -> So101Arm:
    arm = arm_on(link, **kw)
    await arm.connect()
    await arm.initialize()
    assert arm.status is RobotStatus.READY
    return arm


# ---------------------------------------------------------------- handshake
async def test_connect_reads_the_arm_and_initialise_configures_it(link: BusLink) -> None:
    arm = arm_on(link)
    assert isinstance(arm, Robot)
    await arm.connect()
    assert arm.status is RobotStatus.CONNECTED
    np.testing.assert_allclose(arm.joints, MODEL.pose("rest"), atol=STEP_RAD)
    assert not any(link.servo(i).torque for i in TRUE_CAL.ids)  # connect moves nothing
    status = arm.servo_status()
    assert list(status) == list(NAMES)
    assert status["elbow_flex"].voltage_v == 12.0 and status["elbow_flex"].temperature_c == 30
    assert status["gripper"].errors == () and status["gripper"].missed_reads == 0

    await arm.initialize()  # to the home pose, "ready"
    assert arm.status is RobotStatus.READY
    np.testing.assert_allclose(arm.joints, MODEL.pose("ready"), atol=7 * STEP_RAD)
    for i in TRUE_CAL.ids:
        servo = link.servo(i)
        assert servo.torque and servo.memory[Register.RETURN_DELAY_TIME] == 0
        assert servo.memory[Register.ACCELERATION] == arm.acceleration_register
    assert arm.servo_status()["shoulder_lift"].load_percent > 0  # holding, torque on
    await arm.disconnect()
    assert link.servo(1).torque  # disconnecting does not drop the arm


async def test_a_missing_servo_at_connect_is_named(link: BusLink) -> None:
    link.servo(3).mute = True
    # One try: tried again it says the same (tests/test_so101_startup.py).
    arm = arm_on(link, reply_timeout=SILENT, connect_attempts=1)
    with pytest.raises(DeviceError, match=r"servo 3 \(elbow_flex\) does not answer on"):
        await arm.connect()
    assert arm.status is RobotStatus.ERROR and "elbow_flex" in arm.status_message
    assert arm._serial is None and arm._poller is None  # nothing left half open
    link.servo(3).mute = False
    await arm.connect()
    assert arm.status is RobotStatus.CONNECTED
    await arm.disconnect()


async def test_a_servo_of_another_model_is_refused(link: BusLink) -> None:
    link.servo(5).memory[Register.MODEL_NUMBER : Register.MODEL_NUMBER + 2] = ft.le16(1284)
    with pytest.raises(
        DeviceError, match=r"servo 5 \(wrist_roll\) is a servo of model 1284, not an STS3215"
    ):
        await arm_on(link).connect()


async def test_nothing_on_the_port_is_a_clear_error() -> None:
    with pytest.raises(DeviceError, match="cannot open the servo bus '/dev/does-not-exist'"):
        await So101Arm("/dev/does-not-exist", calibration=TRUE_CAL, connect_attempts=1).connect()


# ---------------------------------------------------------------- reading
class _CountingEvent(threading.Event):
    """The poller's wake-up event, counting the waits between reads."""

    def __init__(self) -> None:
        super().__init__()
        self.waits = 0

    def wait(self, timeout: float | None = None) -> bool:
        self.waits += 1
        return super().wait(timeout)


def reads_in(arm: So101Arm, seconds: float) -> tuple[int, float]:
    """Sync reads completed in a window of at least ``seconds`` (wall clock), and its length:
    the window opens before the first count is taken and closes after the last."""
    t0 = time.monotonic()
    r0 = arm.reads
    time.sleep(seconds)
    r1 = arm.reads
    return r1 - r0, time.monotonic() - t0


async def test_sync_reads_are_paced_at_the_period_and_flat_out_without_it(link: BusLink) -> None:
    # No rate line here (200 Hz paced and 1000-3400 Hz flat out are
    # bench.command_latency --robot so101-emulator's `so101_sync_read_hz`). What holds on
    # any machine: the reads happen, and the paced poller never starts reads closer than
    # its period on average: after a read the next is due a period after the one before
    # (or at once when late, never earlier), so a window of W s holds at most W/period + 3
    # completed reads. A slower or busier machine only reads fewer.
    arm = arm_on(link)
    assert arm.poll_period_s == 0.005  # the default: 200 Hz
    await arm.connect()
    await until(lambda: arm.reads >= 101)
    n, window = await asyncio.to_thread(reads_in, arm, 0.3)
    assert 0 < n <= window / arm.poll_period_s + 3, (n, window)
    await arm.disconnect()
    # Flat out: one read after the other, the poller never waits between them.
    flat_out = arm_on(link, poll_period_s=0.0)
    flat_out._goals.wake = wake = _CountingEvent()
    await flat_out.connect()
    await until(lambda: flat_out.reads >= 301)
    await flat_out.disconnect()
    assert wake.waits == 0


async def test_garbage_on_the_bus_is_skipped(link: BusLink) -> None:
    arm = await ready_arm(link)
    link.bus.garbage = b"\x13\x00\xff\x42"
    await until(lambda: link.bus.garbage == b"")
    reads = arm.reads
    await until(lambda: arm.reads > reads + 2)
    assert arm.status is RobotStatus.READY
    await arm.disconnect()


async def test_a_flood_of_garbage_ends_the_read_at_its_limit(link: BusLink) -> None:
    """MAX_REPLY_JUNK: a read stops taking bytes past its budget; that read misses,
    the next ones do not, and one miss is within the missed-read limit."""
    arm = await ready_arm(link)
    link.bus.garbage = bytes(6000)  # zeros: never a header
    await until(lambda: arm.counters["flooded"] >= 1)
    reads = arm.reads
    await until(lambda: arm.reads > reads + 3)
    assert arm.status is RobotStatus.READY
    assert all(s.missed_reads == 0 for s in arm.servo_status().values())
    await arm.disconnect()


def test_the_missed_read_limit() -> None:
    misses = MissCounter([1, 2], limit=3)
    for _ in range(3):
        assert misses.update([1]) == []  # servo 2 silent three times: within the limit
    assert misses.update([1]) == [2]  # the fourth in a row: lost
    assert misses.update([1, 2]) == [] and misses.missed == {1: 0, 2: 0}
    with pytest.raises(ValueError):
        MissCounter([1], limit=0)


# ---------------------------------------------------------------- moving
async def test_moves_reach_the_target(link: BusLink) -> None:
    arm = await ready_arm(link)
    target = np.array([0.4, -0.3, 0.9, 0.8, -0.5, 0.2])
    await arm.move_joints(target, relative=False)
    assert arm.status is RobotStatus.MOVING
    moved: list[float] = []
    arm.events.moved.subscribe(lambda e: moved.append(e.time))
    await arm.wait_idle(timeout=5)
    assert arm.status is RobotStatus.READY
    np.testing.assert_allclose(arm.joints, target, atol=7 * STEP_RAD)
    for i, goal in zip(TRUE_CAL.ids, TRUE_CAL.to_steps(target), strict=True):
        assert abs(link.servo(i).present_position - goal) <= 1
    assert len(moved) >= 3  # reported while it moved
    assert arm.snapshot().velocities.shape == (6,)
    # The goals went out between reads, and the wait is reported (how long it is, about
    # one read transaction, is bench.command_latency --robot so101-emulator's
    # goal_to_bus_p50_ms/_p99_ms: no line here).
    health = arm.diagnostics()
    waits = health["goal_to_bus_ms"]
    assert waits["n"] >= 2 and 0 <= waits["p50"] <= waits["p99"] <= waits["max"], waits
    assert set(health["servos"]) == set(NAMES) and health["read_rate_hz"] > 0
    assert health["servos"]["gripper"]["temperature_c"] == 30
    await arm.disconnect()


async def test_goals_waiting_for_the_bus_are_replaced_by_newer_ones(link: BusLink) -> None:
    arm = await ready_arm(link)
    first, second = np.array([0.1, 0, 0, 0, 0, 0]), np.array([0.2, 0, 0, 0, 0, 0])
    bus = arm._bus
    assert bus is not None
    with bus.lock:  # the bus busy (a read in flight): goals wait, the newest kept
        await arm.move_joints(first, relative=False)
        await arm.move_joints(second, relative=False)  # taken at once, not waiting
        assert arm._goals.out is not None
        written = len(arm.goal_to_bus_s)
    await arm.wait_idle(timeout=5)
    assert len(arm.goal_to_bus_s) == written + 1  # one goal went out, the second
    np.testing.assert_allclose(arm.joints, second, atol=7 * STEP_RAD)
    await arm.disconnect()


async def test_stop_brakes_without_turning_back(link: BusLink) -> None:
    arm = await ready_arm(link)
    spec = arm.stop_spec
    assert spec.category is StopCategory.CONTROLLED_HOLDING
    assert spec.decel[0] == pytest.approx(10.0, rel=0.01)
    assert 0 < spec.reaction_s - arm.reply_timeout < 0.001  # a silent servo, then the goal
    assert arm_on(link, reply_timeout=0.03).stop_spec.reaction_s < 0.05  # the driver's own
    start = arm.joints[0]
    await arm.move_joints(np.array([1.8, -0.6, 0.6, 1.2, 0.0, 0.5]), relative=False)
    await until(lambda: arm.snapshot().velocities[0] > 1.5)
    await arm.stop()
    await arm.wait_idle(timeout=2)
    assert arm.status is RobotStatus.READY
    stopped = arm.joints[0]
    assert start + 0.1 < stopped < 1.8 - 0.1
    assert link.servo(1).torque  # holding where it stopped
    await arm.disconnect()


# ---------------------------------------------------------------- faults
async def test_a_servo_that_stops_answering_stops_the_arm(link: BusLink) -> None:
    arm = await ready_arm(link, reply_timeout=SILENT)
    await arm.move_joints(np.array([0.3, -0.6, 0.6, 1.2, 0.0, 0.5]), relative=False)
    link.servo(4).mute = True
    await until(lambda: arm.status is RobotStatus.ERROR)  # (the move may end first)
    assert "servo 4 (wrist_flex) stopped answering" in arm.status_message
    assert "4 reads in a row" in arm.status_message  # one past the limit of 3
    assert arm.servo_status()["wrist_flex"].missed_reads > 3
    with pytest.raises(NotReady, match="reconnect"):
        await arm.move_joints(np.zeros(6), relative=False)
    link.servo(4).mute = False
    await arm.connect()
    await arm.initialize()
    assert arm.status is RobotStatus.READY
    await arm.disconnect()


@pytest.mark.parametrize(
    ("bit", "words"),
    [(ErrorBit.OVERLOAD, "overload"), (ErrorBit.OVERHEAT, "overheating")],
)
async def test_overload_and_overheat_stop_the_arm_with_a_clear_message(
    link: BusLink, bit: ErrorBit, words: str
) -> None:
    arm = await ready_arm(link)
    await arm.move_joints(np.array([1.5, -0.6, 0.6, 1.2, 0.0, 0.5]), relative=False)
    # Moving (not yet at speed: on a busy machine the reads that would show the peak
    # may all come late, and the move may end first).
    await until(lambda: abs(arm.snapshot().velocities[0]) > 0.3, what="the pan joint moving")
    link.servo(2).temperature_c = 72
    link.servo(2).error = bit
    await arm.wait_idle(timeout=2)
    assert arm.status is RobotStatus.ERROR
    message = arm.status_message
    assert f"servo 2 (shoulder_lift) reports {words}" in message and "72 °C" in message
    assert "The arm was stopped" in message
    assert words in arm.servo_status()["shoulder_lift"].errors
    # Every servo was given a goal where it can stop: the pan joint brakes short of 1.5.
    await until(lambda: link.servo(1).velocity == 0, timeout=2)
    assert arm.joints[0] < 1.5 - 0.1
    with pytest.raises(NotReady):
        await arm.move_joints(np.zeros(6), relative=True)
    # Still faulted at reconnect: refused with the same message.
    with pytest.raises(DeviceError, match=words):
        await arm.connect()
    link.servo(2).error = 0
    await arm.connect()
    await arm.initialize()
    assert arm.status is RobotStatus.READY
    await arm.disconnect()


# ---------------------------------------------------------------- calibration
async def test_calibration_recorded_by_hand_stored_and_reloaded(
    link: BusLink, tmp_path: Path
) -> None:
    path = tmp_path / "so101-calibration.json"
    arm = arm_on(link, calibration=None, calibration_path=path)
    await arm.connect()  # no file yet: it connects, uncalibrated
    assert not arm.calibrated
    with pytest.raises(NotReady, match="not calibrated"):
        await arm.initialize()
    await arm.connect()
    await arm.release()
    recorder = CalibrationRecorder(MODEL, arm.ids)
    for pose in ("zero", "quarter", "ready"):
        steps = TRUE_CAL.to_steps(recorder.poses[pose])
        for i, s in zip(TRUE_CAL.ids, steps, strict=True):
            link.servo(i).position = float(s) + 3  # a person's hand: a few steps off
        await until(lambda s=steps: arm.raw_positions() == [x + 3 for x in s])  # type: ignore[misc]
        recorder.record_pose(pose, arm.raw_positions(), await arm.read_homing_offsets())
    calibration = recorder.solve()
    for got, want in zip(calibration.joints, TRUE_CAL.joints, strict=True):
        assert got.direction == want.direction and got.id == want.id
        assert got.zero_steps == pytest.approx(want.zero_steps + 3, abs=1)
        assert got.homing_offset == 0
    arm.set_calibration(calibration)  # and stored
    np.testing.assert_allclose(arm.joints, MODEL.pose("ready"), atol=2 * STEP_RAD)
    await arm.disconnect()

    again = arm_on(link, calibration=None, calibration_path=path)
    await again.connect()  # reloaded from the file
    assert again.calibration == calibration
    doc = json.loads(path.read_text())
    assert doc["format"] == "telerobot-so101-calibration" and doc["version"] == 1
    assert doc["joints"]["shoulder_lift"]["direction"] == -1
    await again.initialize()
    np.testing.assert_allclose(again.joints, MODEL.pose("ready"), atol=7 * STEP_RAD)
    await again.disconnect()

    # The servos no longer hold the offset the calibration was recorded with.
    link.servo(2).memory[Register.HOMING_OFFSET : Register.HOMING_OFFSET + 2] = ft.le16(
        ft.encode_signed(-100, 11)
    )
    with pytest.raises(DeviceError, match=r"servo 2 \(shoulder_lift\) holds Homing_Offset -100"):
        await again.connect()


async def test_a_corrupt_calibration_file_is_refused(link: BusLink, tmp_path: Path) -> None:
    path = tmp_path / "cal.json"
    path.write_text('{"format": "telerobot-so101-calibration", "version": 1, "joi')
    arm = arm_on(link, calibration=None, calibration_path=path)
    with pytest.raises(DeviceError, match=r"calibration .*cal\.json cannot be used .*record it"):
        await arm.connect()
    assert arm.status is RobotStatus.ERROR
    path.write_text(json.dumps({"format": "telerobot-so101-calibration", "version": 7}))
    with pytest.raises(DeviceError, match="not a version-1 telerobot-so101-calibration file"):
        So101Calibration.load(path, NAMES)
    doc = TRUE_CAL.to_json()
    del doc["joints"]["gripper"]
    path.write_text(json.dumps(doc))
    with pytest.raises(DeviceError, match="no calibration for gripper"):
        So101Calibration.load(path, NAMES)
    doc = TRUE_CAL.to_json()
    doc["joints"]["gripper"]["direction"] = 0
    path.write_text(json.dumps(doc))
    with pytest.raises(DeviceError, match=r"direction 0 is not \+1 or -1"):
        So101Calibration.load(path, NAMES)
    assert So101Calibration.load(tmp_path / "none.json", NAMES) is None


def test_calibration_save_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cal.json"
    TRUE_CAL.save(path)
    before = path.read_text()

    def crash(*args: object, **kw: object) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(json, "dump", crash)
    with pytest.raises(OSError, match="disk full"):
        TRUE_CAL.save(path)
    assert path.read_text() == before and list(tmp_path.iterdir()) == [path]


def test_calibration_needs_poses_that_move_every_joint() -> None:
    recorder = CalibrationRecorder(MODEL)
    for pose in ("zero", "ready", "rest"):
        recorder.record_pose(pose, TRUE_CAL.to_steps(MODEL.pose(pose)))
    with pytest.raises(InvalidCommand, match=r"shoulder_pan \(servo 1\): .*record 'quarter'") as e:
        recorder.solve()
    assert "wrist_roll (servo 5)" in str(e.value) and "elbow_flex" not in str(e.value)
    with pytest.raises(InvalidCommand, match="no pose 'upright'"):
        recorder.record_pose("upright", [0] * 6)
    with pytest.raises(InvalidCommand, match="two poses at least"):
        CalibrationRecorder(MODEL).solve()


def test_calibration_refuses_a_pose_not_reached() -> None:
    recorder = CalibrationRecorder(MODEL)
    recorder.record_pose("zero", TRUE_CAL.to_steps(np.zeros(6)))
    quarter = TRUE_CAL.to_steps(np.full(6, math.pi / 2))
    quarter[2] = TRUE_CAL.to_steps(np.full(6, math.pi / 4))[2]  # the elbow left at 45°
    recorder.record_pose("quarter", quarter)
    with pytest.raises(InvalidCommand, match=r"elbow_flex \(servo 3\): the servo turned 50 %"):
        recorder.solve()


def test_calibration_refuses_a_range_across_the_wrap() -> None:
    recorder = CalibrationRecorder(MODEL)
    shifted = So101Calibration(
        NAMES, tuple(JointCalibration(j.id, j.zero_steps, j.direction) for j in TRUE_CAL.joints)
    )
    zero = shifted.to_steps(np.zeros(6))
    zero[0] = 300  # the pan joint's zero 300 steps above the wrap: its range crosses it
    quarter = shifted.to_steps(np.full(6, math.pi / 2))
    quarter[0] = 300 + 1024
    recorder.record_pose("zero", zero)
    recorder.record_pose("quarter", quarter)
    with pytest.raises(InvalidCommand, match=r"shoulder_pan .*across the servo's 0/4095 wrap"):
        recorder.solve()


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"zero_steps": float("nan")}, "is not a position"),
        ({"zero_steps": 5000}, "is not a position"),
        ({"id": 300}, "is not a bus id"),
        ({"direction": 2}, "is not \\+1 or -1"),
    ],
)
def test_a_calibration_file_with_impossible_values_is_refused(
    tmp_path: Path, change: dict[str, object], why: str
) -> None:
    doc = TRUE_CAL.to_json()
    doc["joints"]["elbow_flex"].update(change)
    path = tmp_path / "cal.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DeviceError, match=why):
        So101Calibration.load(path, NAMES)
    doc = TRUE_CAL.to_json()
    doc["joints"]["gripper"]["id"] = 1  # the pan's servo twice
    path.write_text(json.dumps(doc))
    with pytest.raises(DeviceError, match="the same servo"):
        So101Calibration.load(path, NAMES)


def test_calibration_maps_angles_to_steps_and_back() -> None:
    q = np.array([0.5, -1.0, 1.2, -1.5, 2.5, 1.0])
    steps = TRUE_CAL.to_steps(q)
    np.testing.assert_allclose(TRUE_CAL.to_radians(steps), q, atol=STEP_RAD)
    assert TRUE_CAL.to_steps(np.zeros(6))[1] == 2100
    assert TRUE_CAL.to_steps([0, 0.1, 0, 0, 0, 0])[1] < 2100  # mounted the other way


def test_lerobot_calibration_imports(tmp_path: Path) -> None:
    doc = {
        name: {
            "id": i + 1,
            "drive_mode": 0,
            "homing_offset": 10 * i,
            "range_min": 800,
            "range_max": 3200,
        }
        for i, name in enumerate(NAMES)
    }
    doc["gripper"] = {
        "id": 6,
        "drive_mode": 0,
        "homing_offset": -5,
        "range_min": 2000,
        "range_max": 3300,
    }
    path = tmp_path / "follower.json"
    path.write_text(json.dumps(doc, indent=4))
    cal = from_lerobot(path, MODEL)
    assert cal.joints[0] == JointCalibration(1, 2000.0, 1, 0)
    assert cal.joints[3].homing_offset == 30
    lower = MODEL.qlim[5][0]
    assert cal.to_steps(np.array([0, 0, 0, 0, 0, lower]))[5] == 2000  # closed: range_min
    del doc["gripper"]
    path.write_text(json.dumps(doc))
    with pytest.raises(DeviceError, match=r"LeRobot calibration .* no 'gripper'"):
        from_lerobot(path, MODEL)


# ---------------------------------------------------------------- settings
def test_the_registry_builds_it_from_the_settings(tmp_path: Path) -> None:
    assert load_driver("robot", "so101") is So101Arm
    settings = Settings(
        robot="so101",
        robot_model="so101",
        so101_port="socket://127.0.0.1:5001",
        so101_baudrate=500_000,
        state_dir=tmp_path,
        home_pose="zero",
    )
    arm = build_robot(settings)
    assert isinstance(arm, So101Arm) and isinstance(arm, Robot)
    assert (arm.port_name, arm.baudrate) == ("socket://127.0.0.1:5001", 500_000)
    assert arm.calibration_path == tmp_path / CALIBRATION_FILE
    np.testing.assert_allclose(arm.home, np.zeros(6))
    assert describe_robot(settings) == "the SO-101 on socket://127.0.0.1:5001"
    own = build_robot(settings.model_copy(update={"so101_calibration": tmp_path / "a.json"}))
    assert isinstance(own, So101Arm) and own.calibration_path == tmp_path / "a.json"
    with pytest.raises(InvalidCommand, match="set robot_model = 'so101'"):
        build_robot(Settings(robot="so101"))


async def test_a_blocked_joint_ends_the_move_where_it_stopped(link: BusLink) -> None:
    """The gripper closing on an object never reaches its goal: once every servo has
    been at rest for SETTLE_READS reads the move is over, the arm READY."""
    arm = await ready_arm(link)
    link.servo(6).blocked = True
    before = arm.joints[5]
    reads = arm.reads
    await arm.move_joints(np.array([0.0, -0.6, 0.6, 1.2, 0.0, 0.0]), relative=False)
    await arm.wait_idle(timeout=5)
    assert arm.status is RobotStatus.READY
    assert arm.joints[5] == pytest.approx(before, abs=STEP_RAD)
    assert arm.reads - reads >= SETTLE_READS
    # The goal it never reached is withdrawn: freed, the servo stays where it stopped.
    link.servo(6).blocked = False
    await asyncio.sleep(0.3)
    assert arm.joints[5] == pytest.approx(before, abs=2 * STEP_RAD)
    await arm.disconnect()


async def test_a_fault_is_not_lost_when_the_event_loop_is_late(link: BusLink) -> None:
    """The poller faults the arm while the loop is busy and more readings follow: the
    fault is kept apart from them, and no goal goes out meanwhile."""
    arm = await ready_arm(link)
    link.servo(2).error = ErrorBit.OVERLOAD
    time.sleep(0.05)  # noqa: ASYNC251  (the event loop held on purpose: ten readings come)
    link.servo(2).error = 0
    time.sleep(0.05)  # noqa: ASYNC251  (and more without the fault)
    with pytest.raises(DeviceError, match="overload"):
        await arm.move_joints(np.array([0.3, -0.6, 0.6, 1.2, 0.0, 0.5]), relative=False)
    await asyncio.sleep(0.05)
    assert arm.status is RobotStatus.ERROR and "overload" in arm.status_message
    await arm.disconnect()


async def test_a_stop_is_not_overtaken_by_a_goal_still_waiting_for_the_bus(link: BusLink) -> None:
    arm = await ready_arm(link)
    await arm.move_joints(np.array([1.5, -0.6, 0.6, 1.2, 0.0, 0.5]), relative=False)
    await until(lambda: arm.snapshot().velocities[0] > 1.0)
    bus = arm._bus
    assert bus is not None
    far = np.array([-1.5, -0.6, 0.6, 1.2, 0.0, 0.5])
    with bus.lock:  # a read in flight: the next goal waits in the slot
        await arm.move_joints(far, relative=False)
        at_stop = arm.joints[0]
        stopping = asyncio.ensure_future(arm.stop())  # its brake waits for the bus too
        await asyncio.sleep(0.01)
    await stopping
    await arm.wait_idle(timeout=3)
    await asyncio.sleep(0.2)
    # Braked on its way to 1.5, never sent back toward -1.5: the waiting goal was dropped.
    assert arm.joints[0] >= at_stop - 2 * STEP_RAD
    far_steps = TRUE_CAL.to_steps(far)[0]
    assert abs(link.servo(1).u16(Register.GOAL_POSITION) - far_steps) > 100
    # The rule itself, without the race: a brake drops the goal waiting in the slot.
    with arm._goals.lock:
        arm._goals.out = (b"not sent", time.monotonic())
    reading = arm._latest
    assert reading is not None
    arm._brake(bus, reading.servos)
    assert arm._goals.out is None
    await arm.disconnect()


async def test_a_dropped_link_puts_the_arm_in_error() -> None:
    with BusLink.on_tcp(FeetechBusEmulator(start=start_steps())) as link:
        arm = await ready_arm(link)
        link.drop_client()
        await until(lambda: arm.status is RobotStatus.ERROR)
        assert "the servo bus on 'socket://" in arm.status_message
        await arm.connect()  # the emulator takes a new connection
        await arm.initialize()
        assert arm.status is RobotStatus.READY
        await arm.disconnect()


def test_calibration_refuses_a_pose_off_the_others() -> None:
    recorder = CalibrationRecorder(MODEL)
    for pose in ("zero", "quarter", "ready"):
        steps = TRUE_CAL.to_steps(recorder.poses[pose])
        if pose == "ready":
            steps[3] += round(math.radians(45) * STEPS_PER_RADIAN)  # the wrist not there
        recorder.record_pose(pose, steps)
    with pytest.raises(InvalidCommand, match=r"wrist_flex \(servo 4\): one pose is \d+° off"):
        recorder.solve()


async def test_the_calibrate_command_records_by_hand_and_writes_the_file(
    link: BusLink, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from telerobot.drivers.robot.so101 import calibrate
    from telerobot.drivers.robot.so101.calibrate import record

    monkeypatch.setattr(
        calibrate, "So101Arm", functools.partial(So101Arm, reply_timeout=REPLY_TIMEOUT)
    )

    out = tmp_path / "cal.json"
    said: list[str] = []

    def person(prompt: str) -> str:  # moves the arm where the prompt says, then Enter
        pose = prompt.split("'")[1]
        steps = TRUE_CAL.to_steps(CalibrationRecorder(MODEL).poses[pose])
        for i, s in zip(TRUE_CAL.ids, steps, strict=True):
            link.servo(i).position = float(s)
        time.sleep(0.1)  # a few of the driver's reads
        said.append(prompt)
        return ""

    await record(link.url, out, baudrate=ft.DEFAULT_BAUDRATE, ask=person, say=said.append)
    assert [p.split("'")[1] for p in said if p.startswith("Move")] == ["zero", "quarter"]
    assert not any(link.servo(i).torque for i in TRUE_CAL.ids)  # released, never moved
    stored = So101Calibration.load(out, NAMES)
    assert stored is not None
    for got, want in zip(stored.joints, TRUE_CAL.joints, strict=True):
        assert got.direction == want.direction and got.zero_steps == pytest.approx(
            want.zero_steps, abs=1
        )
    assert said[-1] == f"Calibration written to {out}"


def test_the_calibrate_command_says_when_there_is_no_arm(tmp_path: Path) -> None:
    import subprocess
    import sys

    exe = Path(sys.executable).parent / "telerobot"
    out = subprocess.run(
        [
            str(exe),
            "so101-calibrate",
            "--port",
            "socket://127.0.0.1:9",
            "--out",
            str(tmp_path / "c"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 1 and "cannot open the servo bus" in out.stdout
    assert not (tmp_path / "c").exists()
