from __future__ import annotations

import math

import numpy as np
import pytest

from telerobot.drivers.base import (
    InvalidCommand,
    JointLimitError,
    NotReady,
    RobotMoved,
    RobotStatus,
    StatusChanged,
    StopCategory,
    UnreachablePose,
    WorkingFrame,
)
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.motion import PUMA_STOP_DECEL, stop_distance, stop_time
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from tests.support import TOKEN
from tests.support.clock import run_with_clock


def rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
async def robot(clock: ManualClock) -> SimPuma:
    r = SimPuma(clock=clock, kinematics=Puma560Kinematics(tool_transform(0.1)))
    await r.connect()
    await run_with_clock(clock, r.initialize())
    return r


async def test_lifecycle_statuses_and_events(clock: ManualClock) -> None:
    r = SimPuma(clock=clock)
    statuses: list[StatusChanged] = []
    moved: list[RobotMoved] = []
    r.events.status_changed.subscribe(statuses.append)
    r.events.moved.subscribe(moved.append)
    assert r.status is RobotStatus.NOT_CONNECTED
    await r.connect()
    await run_with_clock(clock, r.initialize())
    assert [s.new for s in statuses] == [
        RobotStatus.CONNECTED,
        RobotStatus.WAITING,
        RobotStatus.MOVING,
        RobotStatus.READY,
    ]
    np.testing.assert_allclose(r.joints, NAMED_POSES["qn"], atol=1e-9)
    assert len(moved) > 10  # reported along the way, every 20 ms
    np.testing.assert_allclose(moved[-1].joints, NAMED_POSES["qn"], atol=1e-9)
    # qz → qn is a 180° move of joint 3 at 1 rad/s: it took the time it takes.
    assert clock.now() == pytest.approx(math.pi + 0.5, abs=0.15)
    await r.disconnect()
    assert r.status is RobotStatus.NOT_CONNECTED


@pytest.mark.parametrize("at_home", [False, True])
async def test_the_server_switches_the_simulation_on_at_its_start_pose_or_at_home(
    clock: ManualClock, at_home: bool
) -> None:
    from telerobot.server.devices import build_robot
    from telerobot.server.settings import Settings

    r = build_robot(Settings(operator_token=TOKEN, sim_starts_at_home=at_home), clock=clock)
    await r.connect()
    np.testing.assert_allclose(r.joints, NAMED_POSES["qn" if at_home else "qz"], atol=1e-9)
    await run_with_clock(clock, r.initialize())
    assert r.status is RobotStatus.READY
    np.testing.assert_allclose(r.joints, NAMED_POSES["qn"], atol=1e-9)
    # From its start pose the move home takes its time; at home, none.
    assert clock.now() == (
        pytest.approx(0.0, abs=0.1) if at_home else pytest.approx(math.pi + 0.5, abs=0.15)
    )


async def test_a_move_takes_time_and_reports_moving(robot: SimPuma, clock: ManualClock) -> None:
    target = robot.joints + np.array([0.5, 0, 0, 0, 0, 0])
    await robot.move_joints(target, relative=False)
    assert robot.status is RobotStatus.MOVING
    await clock.advance(0.5)
    assert robot.status is RobotStatus.MOVING
    assert 0.0 < robot.joints[0] < 0.5
    await clock.advance(2.0)
    assert robot.status is RobotStatus.READY
    np.testing.assert_allclose(robot.joints, target, atol=1e-9)


async def test_a_motion_that_ends_while_it_is_being_reported_still_ends_ready(
    robot: SimPuma, clock: ManualClock
) -> None:
    # Reading the joints to report a move syncs the motion; when a thread switch lets
    # time pass right there, the motion can end inside the report. The status must
    # still return to READY (it used to stay MOVING for good: a rare CI failure).
    report = robot._report_moved

    def report_and_finish() -> None:
        robot._motion.advance(10.0)  # the motion ends during the report
        report()

    robot._report_moved = report_and_finish  # type: ignore[method-assign]
    await robot.move_joints(robot.joints + np.array([0.5, 0, 0, 0, 0, 0]), relative=False)
    assert robot.status is RobotStatus.MOVING
    await clock.advance(0.1)
    assert robot.status is RobotStatus.READY


async def test_increments_accumulate_on_the_commanded_target(
    robot: SimPuma, clock: ManualClock
) -> None:
    start = robot.joints
    for _ in range(10):  # a stream of increments while the arm is still moving
        await robot.move_joints(np.array([0.01, 0, 0, 0, 0, -0.02]), relative=True)
        await clock.advance(0.01)
    await run_with_clock(clock, robot.wait_idle())
    np.testing.assert_allclose(robot.joints, start + [0.1, 0, 0, 0, 0, -0.2], atol=1e-9)


@pytest.mark.parametrize("frame", list(WorkingFrame))
async def test_cartesian_increment_in_each_frame(
    robot: SimPuma, clock: ManualClock, frame: WorkingFrame
) -> None:
    T0 = robot.kinematics.fk(robot.joints).copy()
    dX, dM = np.array([0.02, -0.01, 0.03]), rot_z(0.1)
    await robot.move_cartesian(dX, dM, relative=True, frame=frame)
    await run_with_clock(clock, robot.wait_idle())
    T = robot.pose.matrix()
    if frame is WorkingFrame.BASE:
        np.testing.assert_allclose(T[:3, 3], T0[:3, 3] + dX, atol=1e-8)
        np.testing.assert_allclose(T[:3, :3], dM @ T0[:3, :3], atol=1e-8)
    elif frame is WorkingFrame.TOOL:
        np.testing.assert_allclose(T[:3, 3], T0[:3, 3] + T0[:3, :3] @ dX, atol=1e-8)
        np.testing.assert_allclose(T[:3, :3], T0[:3, :3] @ dM, atol=1e-8)
    else:  # the wrist centre moves by dX in the flange frame; the tool swings around it
        W0 = T0 @ np.linalg.inv(tool_transform(0.1))
        W = T @ np.linalg.inv(tool_transform(0.1))
        np.testing.assert_allclose(W[:3, 3], W0[:3, 3] + W0[:3, :3] @ dX, atol=1e-8)
        np.testing.assert_allclose(W[:3, :3], W0[:3, :3] @ dM, atol=1e-8)


async def test_absolute_cartesian_move(robot: SimPuma, clock: ManualClock) -> None:
    T = robot.pose.matrix()
    p = T[:3, 3] + [0.0, 0.1, -0.05]
    await robot.move_cartesian(p, T[:3, :3], relative=False)
    await run_with_clock(clock, robot.wait_idle())
    np.testing.assert_allclose(robot.pose.position, p, atol=1e-8)


@pytest.mark.parametrize(
    ("call", "error"),
    [
        (lambda r: r.move_joints([math.nan, 0, 0, 0, 0, 0], relative=True), InvalidCommand),
        (lambda r: r.move_joints([0, 0, 0], relative=True), InvalidCommand),
        (
            lambda r: r.move_joints([0, math.radians(230), 0, 0, 0, 0], relative=False),
            JointLimitError,
        ),
        (lambda r: r.move_cartesian([3.0, 0, 0.5], np.eye(3), relative=False), UnreachablePose),
        (lambda r: r.move_cartesian([0, 0, math.inf], np.eye(3), relative=True), InvalidCommand),
        (lambda r: r.move_cartesian([0, 0, 0], np.eye(3) * 1.1, relative=True), InvalidCommand),
    ],
)
async def test_bad_commands_are_refused_and_nothing_moves(
    robot: SimPuma, clock: ManualClock, call, error
) -> None:  # type: ignore[no-untyped-def]
    before = robot.joints
    with pytest.raises(error):
        await call(robot)
    await clock.advance(1.0)
    assert robot.status is RobotStatus.READY
    np.testing.assert_array_equal(robot.joints, before)


async def test_moves_are_refused_until_initialised(clock: ManualClock) -> None:
    r = SimPuma(clock=clock)
    with pytest.raises(NotReady, match="connect and initialise"):
        await r.move_joints(np.zeros(6), relative=True)
    await r.connect()
    with pytest.raises(NotReady, match="initialise it first"):
        await r.move_joints(np.zeros(6), relative=True)
    np.testing.assert_array_equal(r.joints, NAMED_POSES["qz"])


async def test_joint_offsets_correct_the_reported_angles(
    robot: SimPuma, clock: ManualClock
) -> None:
    raw = robot.joints
    robot.joint_offsets = np.array([0.01, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(robot.joints, raw + [0.01, 0, 0, 0, 0, 0])
    await robot.move_joints(np.zeros(6) + [0.1, 0, 0, 0, 0, 0] + raw, relative=False)
    with pytest.raises(NotReady):
        robot.joint_offsets = np.zeros(6)
    await run_with_clock(clock, robot.wait_idle())
    np.testing.assert_allclose(robot.joints, raw + [0.1, 0, 0, 0, 0, 0], atol=1e-9)


async def test_stop_brakes_and_the_arm_comes_to_rest(robot: SimPuma, clock: ManualClock) -> None:
    start = robot.joints[0]
    await robot.move_joints(np.array([1.5, 0, 0, 0, 0, 0]), relative=True)
    await clock.advance(0.8)
    await robot.stop()
    await clock.advance(1.0)
    assert robot.status is RobotStatus.READY
    assert start + 0.3 < robot.joints[0] < start + 1.0  # stopped well short of the target
    # The next increment is relative to where the arm stopped, not the abandoned target.
    stopped = robot.joints
    await robot.move_joints(np.array([0.05, 0, 0, 0, 0, 0]), relative=True)
    await run_with_clock(clock, robot.wait_idle())
    assert robot.joints[0] == pytest.approx(stopped[0] + 0.05)


async def test_a_stop_from_full_speed_brakes_at_the_limit_within_its_time_and_distance(
    robot: SimPuma, clock: ManualClock
) -> None:
    spec = robot.stop_spec
    assert spec.category is StopCategory.CONTROLLED_HOLDING and spec.reaction_s == 0.0
    np.testing.assert_array_equal(spec.decel, PUMA_STOP_DECEL)
    await robot.move_joints(np.array([1.5, 0, 0, 2.0, 0, 0]), relative=True)
    await clock.advance(0.8)  # joint 1 cruising at 1 rad/s, joint 4 at 4/3 rad/s
    q0, v0 = robot.joints, robot.joint_velocities
    assert v0[0] == pytest.approx(1.0)
    T, d = stop_time(v0, spec.decel), stop_distance(v0, spec.decel)
    assert pytest.approx(0.1) == T and d[0] == pytest.approx(0.05)
    await robot.stop()
    await clock.advance(T / 2)
    np.testing.assert_allclose(robot.joint_velocities, v0 / 2, atol=1e-9)  # at the limit
    await clock.advance(T / 2)
    assert not np.any(robot.joint_velocities)
    np.testing.assert_allclose(robot.joints, q0 + d, atol=1e-9)
    await clock.advance(robot.report_period)
    assert robot.status is RobotStatus.READY
    np.testing.assert_allclose(robot.target_joints, q0 + d, atol=1e-9)


async def test_wait_idle_times_out_in_clock_time(robot: SimPuma, clock: ManualClock) -> None:
    await robot.move_joints(np.array([1.0, 0, 0, 0, 0, 0]), relative=True)
    with pytest.raises(TimeoutError, match="still MOVING"):
        await run_with_clock(clock, robot.wait_idle(timeout=0.3))
