"""ValSerialPuma against the emulated controller over a real pseudo-terminal and a
real TCP socket (docs/architecture.md, rule 4: the byte protocol against an emulator)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Iterator

import numpy as np
import pytest

from telerobot.drivers.base import DeviceError, NotReady, RobotStatus, SerialSettings, StopCategory
from telerobot.drivers.robot.motion import PUMA_STOP_DECEL, stop_time
from telerobot.drivers.robot.puma560 import val_protocol as vp
from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES
from telerobot.drivers.robot.puma560.val_emulator import EmulatorLink, ValControllerEmulator
from telerobot.drivers.robot.puma560.val_serial import ValSerialPuma

FAST = 0.02  # emulated moves take 2 % of their real time


@pytest.fixture(params=["pty", "tcp"])
def link(request: pytest.FixtureRequest) -> Iterator[EmulatorLink]:
    emulator = ValControllerEmulator(time_scale=FAST)
    make = EmulatorLink.on_pty if request.param == "pty" else EmulatorLink.on_tcp
    with make(emulator) as running:
        yield running


@pytest.fixture(params=["pty", "tcp"])
def slow_link(request: pytest.FixtureRequest) -> Iterator[EmulatorLink]:
    """Moves at a quarter of their real time, from the home pose: long enough to be
    stopped part-way."""
    emulator = ValControllerEmulator(list(np.degrees(NAMED_POSES["qn"])), time_scale=0.25)
    make = EmulatorLink.on_pty if request.param == "pty" else EmulatorLink.on_tcp
    with make(emulator) as running:
        yield running


def robot_on(link: EmulatorLink, **kw: float) -> ValSerialPuma:
    return ValSerialPuma(
        SerialSettings(port=link.url, reply_timeout=kw.get("reply_timeout", 1.0), move_margin=0.5)
    )


async def ready_robot(link: EmulatorLink, **kw: float) -> ValSerialPuma:
    """A driver on ``link``, connected and initialised (at the home pose, READY)."""
    robot = robot_on(link, **kw)
    await robot.connect()
    await robot.initialize()
    assert robot.status is RobotStatus.READY
    return robot


async def test_initialise_uploads_the_resident_program_and_moves_home(link: EmulatorLink) -> None:
    robot = robot_on(link)
    lines: list[str] = []
    robot.events.data_received.subscribe(lines.append)
    await robot.connect()
    assert robot.status is RobotStatus.CONNECTED
    await robot.initialize()
    assert robot.status is RobotStatus.READY
    assert link.emulator.loaded["TRINC"] == list(vp.RESIDENT_PROGRAM)
    assert link.emulator.mode == "program"
    np.testing.assert_allclose(robot.joints, NAMED_POSES["qn"], atol=1e-6)
    np.testing.assert_allclose(np.radians(link.emulator.joints_deg), NAMED_POSES["qn"], atol=1e-6)
    assert vp.READY_BANNER in lines and any(line.startswith("DONE") for line in lines)
    await robot.disconnect()


async def test_streamed_increments_coalesce_and_arrive(link: EmulatorLink) -> None:
    robot = await ready_robot(link)
    moves_before = link.emulator.moves
    for _ in range(25):
        await robot.move_joints(np.array([0.004, 0, 0, 0, -0.002, 0]), relative=True)
    assert robot.status is RobotStatus.MOVING
    await robot.wait_idle(timeout=10)
    assert robot.status is RobotStatus.READY
    np.testing.assert_allclose(
        robot.joints, NAMED_POSES["qn"] + [0.1, 0, 0, 0, -0.05, 0], atol=2e-6
    )
    # 25 commands, far fewer serial moves: newer targets replace older ones on a busy link.
    assert 1 <= link.emulator.moves - moves_before < 25
    await robot.disconnect()


async def test_cartesian_move_through_the_controller(link: EmulatorLink) -> None:
    robot = await ready_robot(link)
    p0 = robot.pose.position
    await robot.move_cartesian(np.array([0, 0, 0.05]), np.eye(3), relative=True)
    await robot.wait_idle(timeout=10)
    np.testing.assert_allclose(robot.pose.position, p0 + [0, 0, 0.05], atol=1e-5)
    await robot.disconnect()


async def test_silent_controller_gives_error_then_reconnect_recovers(link: EmulatorLink) -> None:
    robot = await ready_robot(link, reply_timeout=0.3)
    link.emulator.fault = "mute"
    await robot.move_joints(np.array([0.01, 0, 0, 0, 0, 0]), relative=True)
    await robot.wait_idle(timeout=5)
    assert robot.status is RobotStatus.ERROR
    assert "no ACK" in robot.status_message and link.url in robot.status_message
    with pytest.raises(NotReady, match="reconnect"):
        await robot.move_joints(np.zeros(6), relative=True)
    link.emulator.fault = None
    await robot.connect()
    await robot.initialize()
    assert robot.status is RobotStatus.READY
    await robot.disconnect()


async def test_garbled_reply_gives_a_clear_error(link: EmulatorLink) -> None:
    robot = await ready_robot(link)
    link.emulator.fault = "garble"
    await robot.move_joints(np.array([0.01, 0, 0, 0, 0, 0]), relative=True)
    await robot.wait_idle(timeout=5)
    assert robot.status is RobotStatus.ERROR
    assert "unexpected reply" in robot.status_message
    await robot.disconnect()


async def test_controller_refusal_is_reported(link: EmulatorLink) -> None:
    robot = await ready_robot(link)
    # Wrong zero offsets: our model thinks joint 5 has room, the controller does not.
    link.emulator.joints_deg[4] = 99.0
    robot.joint_offsets = np.radians([0, 0, 0, 0, -60.0, 0])
    await robot.move_joints(np.radians([0, 0, 0, 0, 5.0, 0]), relative=True)
    await robot.wait_idle(timeout=5)
    assert robot.status is RobotStatus.ERROR
    assert "refused" in robot.status_message and "joint 5 limit" in robot.status_message
    await robot.disconnect()


async def test_missing_port_is_a_clear_error() -> None:
    robot = ValSerialPuma(SerialSettings(port="/dev/does-not-exist"))
    with pytest.raises(DeviceError, match="cannot open serial port '/dev/does-not-exist'"):
        await robot.connect()
    assert robot.status is RobotStatus.ERROR


async def test_silent_controller_at_connect_is_a_clear_error(link: EmulatorLink) -> None:
    link.emulator.fault = "mute"
    robot = robot_on(link, reply_timeout=0.3)
    with pytest.raises(DeviceError, match=r"no '\.' from the controller .* after 'ABORT'"):
        await robot.connect()
    assert robot.status is RobotStatus.ERROR
    assert robot._reader is None and robot._serial is None  # nothing left half open
    link.emulator.fault = None
    await robot.connect()
    assert robot.status is RobotStatus.CONNECTED
    await robot.disconnect()


async def test_nothing_listening_is_a_clear_error() -> None:
    robot = ValSerialPuma(SerialSettings(port="socket://127.0.0.1:9"))
    with pytest.raises(DeviceError, match="cannot open serial port"):
        await robot.connect()


async def test_dropped_tcp_link_puts_the_driver_in_error() -> None:
    with EmulatorLink.on_tcp(ValControllerEmulator(time_scale=FAST)) as link:
        robot = await ready_robot(link)
        link.drop_client()
        await robot.move_joints(np.array([0.01, 0, 0, 0, 0, 0]), relative=True)
        await robot.wait_idle(timeout=5)
        assert robot.status is RobotStatus.ERROR
        await robot.connect()  # the emulator accepts a new connection
        await robot.initialize()
        assert robot.status is RobotStatus.READY
        await robot.disconnect()


def test_emulator_holds_lines_while_moving() -> None:
    emu = ValControllerEmulator()
    emu.loaded["TRINC"] = []
    assert emu.receive("EXECUTE TRINC", 0.0) == [vp.READY_BANNER]
    ack = emu.receive(vp.increment_line(1, [10, 0, 0, 0, 0, 0]), 0.0)
    duration = vp.parse_reply(ack[0])
    assert isinstance(duration, vp.Ack) and duration.duration > 0.1
    assert emu.receive("W", 0.01) == []  # TRINC is inside MOVE
    assert emu.poll(0.01) == []
    out = emu.poll(duration.duration + 0.001)
    assert out[0].startswith("DONE 1 10.0000") and out[1].startswith("POS 10.0000")


def test_emulator_abort_brakes_at_the_limit_and_prompts_at_rest() -> None:
    emu = ValControllerEmulator()
    emu.loaded["TRINC"] = []
    assert emu.receive("EXECUTE TRINC", 0.0) == [vp.READY_BANNER]
    ack = vp.parse_reply(emu.receive(vp.increment_line(1, [90, 0, 0, 0, 0, 0]), 0.0)[0])
    assert isinstance(ack, vp.Ack) and ack.duration == pytest.approx(math.pi / 2 + 0.5, abs=1e-3)
    q0, v0 = emu.state_at(1.0)  # cruising at 1 rad/s
    assert v0[0] == pytest.approx(1.0) and q0[0] == pytest.approx(0.75)
    assert emu.receive("ABORT", 1.0) == []  # the prompt comes at rest
    T = stop_time(v0, PUMA_STOP_DECEL)
    assert pytest.approx(0.1) == T
    assert emu.state_at(1.0 + T / 2)[1][0] == pytest.approx(0.5)  # braking at 10 rad/s²
    assert emu.receive("W", 1.01) == []  # lines wait until the arm is at rest
    assert emu.poll(1.0 + T - 1e-3) == []
    assert emu.next_deadline() == pytest.approx(1.0 + T)
    assert emu.poll(1.0 + T) == [vp.PROMPT, "ERR unknown command W", vp.PROMPT]
    assert emu.mode == "monitor" and emu.aborted == 1 and emu.moves == 0
    assert emu.joints_deg[0] == pytest.approx(math.degrees(0.75 + 1.0 * T / 2), abs=1e-4)
    assert emu.receive("ABORT", 2.0) == [vp.PROMPT]  # at rest: at once


async def test_stop_aborts_the_move_on_the_wire_and_the_arm_brakes_to_rest(
    slow_link: EmulatorLink,
) -> None:
    robot = await ready_robot(slow_link)
    spec = robot.stop_spec
    assert spec.category is StopCategory.CONTROLLED_HOLDING
    assert 0.0 < spec.reaction_s < 0.12  # 9600 baud: a line and ABORT, one VAL cycle
    start = robot.joints
    await robot.move_joints(np.array([2.5, 0, 0, 0, 0, 0]), relative=True)  # 0.75 s here
    await asyncio.sleep(0.3)  # joint 1 cruising at 1 rad/s (4 rad/s on this clock)
    await robot.stop()
    await robot.wait_idle(timeout=2)
    # The increment on the wire did not run to its end (0.45 s more): the arm braked
    # (0.1 s at 10 rad/s², 25 ms on this clock) and the driver read where it stopped,
    # well short of the end below. How long stop() → at rest takes is
    # bench.stopping's `val_serial_stop_s`, not a line here.
    assert robot.status is RobotStatus.READY and slow_link.emulator.aborted == 1
    np.testing.assert_allclose(robot.joints, np.radians(slow_link.emulator.joints_deg), atol=2e-6)
    assert start[0] + 0.3 < robot.joints[0] < start[0] + 2.0  # well short of +2.5
    # And it moves on from there.
    stopped = robot.joints
    await robot.move_joints(np.array([0.05, 0, 0, 0, 0, 0]), relative=True)
    await robot.wait_idle(timeout=2)
    assert robot.status is RobotStatus.READY
    assert robot.joints[0] == pytest.approx(stopped[0] + 0.05, abs=2e-6)
    await robot.disconnect()


async def test_stop_between_increments_sends_no_abort(link: EmulatorLink) -> None:
    robot = await ready_robot(link)
    lines: list[str] = []
    robot.events.data_received.subscribe(lines.append)
    await robot.stop()  # READY: nothing to stop
    await robot.move_joints(np.array([0.01, 0, 0, 0, 0, 0]), relative=True)
    await robot.wait_idle(timeout=5)
    assert robot.status is RobotStatus.READY and link.emulator.aborted == 0
    await robot.disconnect()
