"""Two arms under one DecisionServer (docs/arms.md), in virtual time: each command names
its arm and moves that arm only; one lease covers both; the e-stop, the dead-man and a
lease lost stop both; a force stop of one arm stops that arm alone and says which; a
command that names no arm is refused with the arms' names. And the settings' arms."""

from __future__ import annotations

import numpy as np
import pytest

from telerobot.drivers.base import ForceSample, InvalidCommand, RobotStatus
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell, facing_mounts, mount_transform
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer, SafetyState
from telerobot.server.control.errors import SafetyStop
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.settings import load_settings, parse_arms
from tests.support import TOKEN
from tests.support.clock import run_with_clock
from tests.support.decision import RecordingPuma, recording_puma

STEP = np.array([0.005, 0.0, 0.0])
NO_TURN = np.zeros(3)


async def two_arms(
    clock: ManualClock,
) -> tuple[DecisionServer, RecordingPuma, RecordingPuma, Client]:
    """Two simulated PUMAs, "left" and "right", and "alice" holding the one lease."""
    left, right = await recording_puma(clock), await recording_puma(clock)
    limits = SafetyLimits()
    ds = DecisionServer(
        [
            ArmGuard("left", 1, left, Puma560Kinematics(tool_transform(0.1)), limits),
            ArmGuard("right", 2, right, Puma560Kinematics(tool_transform(0.1)), limits),
        ],
        clock=clock,
        operator_token=TOKEN,
        limits=limits,
    )
    alice = ds.join("alice", TOKEN)
    await ds.take_lease(alice.id)
    return ds, left, right, alice


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


async def test_each_command_moves_the_arm_it_names_and_no_other(clock: ManualClock) -> None:
    ds, left, right, alice = await two_arms(clock)
    applied = await ds.cartesian_increment(alice.id, STEP, NO_TURN, arm="right")
    assert applied.arm == "right" and len(right.sent) == 1 and not left.sent
    await clock.advance(0.01)
    await ds.joint_increment(alice.id, np.full(6, 0.01), arm="left")
    assert len(left.sent) == 1 and len(right.sent) == 1
    # By index, as the wire names them: 1 is the first arm, 2 the second.
    assert ds.arm_at(1).name == "left" and ds.arm_at(2).name == "right"


async def test_two_arms_interleaved_each_get_their_own_speed_allowance(
    clock: ManualClock,
) -> None:
    """Both arms at 100 Hz from one client, the right arm's command 1 ms after the
    left's: each increment is judged against the time since that arm's last one (the
    speed limit once cut the right arm's to the 1 ms between the two)."""
    ds, _, _, alice = await two_arms(clock)
    step = np.array([0.002, 0.0, 0.0])  # 0.2 m/s at 100 Hz: under the 0.25 m/s limit
    for _ in range(5):
        left = await ds.cartesian_increment(alice.id, step, NO_TURN, arm="left")
        await clock.advance(0.001)
        right = await ds.cartesian_increment(alice.id, step, NO_TURN, arm="right")
        await clock.advance(0.009)
    assert left.scale == right.scale == 1.0


async def test_a_command_that_names_no_arm_is_refused_with_the_arms_names(
    clock: ManualClock,
) -> None:
    ds, left, right, alice = await two_arms(clock)
    with pytest.raises(InvalidCommand, match=r"drives 2 arms \(left, right\): name the arm"):
        await ds.cartesian_increment(alice.id, STEP, NO_TURN)
    with pytest.raises(InvalidCommand, match=r"no arm named 'middle'.*left, right"):
        await ds.move_joints(alice.id, NAMED_POSES["qn"], arm="middle")
    with pytest.raises(InvalidCommand, match="no arm 3"):
        ds.arm_at(3)
    with pytest.raises(InvalidCommand, match="name the arm"):
        ds.arm_at(0)  # "the only arm": there are two
    assert not left.sent and not right.sent  # nothing moved


async def test_the_e_stop_stops_both_arms_and_refuses_both(clock: ManualClock) -> None:
    ds, left, right, alice = await two_arms(clock)
    stops = {"left": 0, "right": 0}
    for name, robot in (("left", left), ("right", right)):
        original = robot.stop

        async def counted(name: str = name, original=original) -> None:  # type: ignore[no-untyped-def]
            stops[name] += 1
            await original()

        robot.stop = counted  # type: ignore[method-assign]
    await ds.estop(None, "test")
    assert stops == {"left": 1, "right": 1}
    for arm in ("left", "right"):
        with pytest.raises(SafetyStop, match="e-stop"):
            await ds.cartesian_increment(alice.id, STEP, NO_TURN, arm=arm)


async def test_the_dead_man_and_a_lost_lease_stop_both_arms(clock: ManualClock) -> None:
    ds, left, right, alice = await two_arms(clock)
    await ds.cartesian_increment(alice.id, STEP, NO_TURN, arm="left")
    await ds.cartesian_increment(alice.id, STEP, NO_TURN, arm="right")
    assert left.status is RobotStatus.MOVING and right.status is RobotStatus.MOVING
    await quiet_for(ds, clock, 0.3)  # silent past the dead-man's limit: both halted
    assert ds.state().halted and ds.lease_holder == alice.id
    assert left.status is not RobotStatus.MOVING and right.status is not RobotStatus.MOVING
    await quiet_for(ds, clock, ds.limits.lease_grace_s)  # past the grace: lost for both
    assert ds.lease_holder is None


async def quiet_for(ds: DecisionServer, clock: ManualClock, seconds: float) -> None:
    """``seconds`` of virtual time with the dead-man checked every tick, as it runs."""
    for _ in range(round(seconds / ds.limits.tick_s)):
        await clock.advance(ds.limits.tick_s)
        await ds.tick()


async def test_a_force_stop_on_one_arm_stops_that_arm_only_and_names_it(
    clock: ManualClock,
) -> None:
    ds, _, _, alice = await two_arms(clock)
    said: list[SafetyState] = []
    ds.events.safety_changed.subscribe(said.append)
    push = (0.0, 0.0, 100.0, 0.0, 0.0, 0.0)  # 100 N, past the 60 N limit
    ds.on_force(ForceSample(1, clock.now(), push), ds.arm("right"))
    await run_with_clock(clock, _settle())
    assert said[-1].force_limited and said[-1].force_limited_arms == ("right",)
    # The left arm goes on; the right takes only moves that back away, and says so.
    await ds.cartesian_increment(alice.id, STEP, NO_TURN, arm="left")
    with pytest.raises(SafetyStop, match=r"^right: force limit"):
        await ds.joint_increment(alice.id, np.full(6, 0.01), arm="right")
    ds.on_force(ForceSample(2, clock.now(), (0.0,) * 6), ds.arm("right"))
    assert not ds.state().force_limited


async def _settle() -> None:
    import asyncio

    await asyncio.sleep(0)


def test_the_settings_name_the_arms_and_refuse_what_cannot_be() -> None:
    assert parse_arms("left=so101:sim,right=so101:so101:netft") == {
        "left": {"robot_model": "so101", "robot": "sim"},
        "right": {"robot_model": "so101", "robot": "so101", "force": "netft"},
    }
    settings = load_settings(arms="left=so101:sim,right=puma560:sim", viewer=False)
    arms = settings.arm_settings()
    assert [(n, a.robot_model) for n, a in arms] == [("left", "so101"), ("right", "puma560")]
    assert arms[0][1].home_pose_name == "ready"  # its model's home, not the server's
    assert load_settings().arm_names == ["arm"]  # one arm, as before
    for spec, why in (
        ("left=so101:sim", "two arms or more"),
        ("left=so101:sim,left=so101:sim", "named twice"),
        ("left=so101,right=nope:sim", "unknown robot model 'nope'"),
        ("left=so101:sim,right so=so101:sim", "not an arm name"),
        ("left:so101", "not name=model"),
        (",".join(f"a{i}=so101:sim" for i in range(9)), "at most 8 arms, not 9"),
    ):
        with pytest.raises(ValueError, match=why):
            load_settings(arms=spec)
    with pytest.raises(ValueError, match="http_port is the server's"):
        load_settings(arms={"left": {"http_port": 1}, "right": {}})


def test_two_arms_face_each_other_and_each_feels_the_block_in_its_own_frame() -> None:
    left, right = facing_mounts(0.4, (0.0, 0.0, -0.16))
    assert np.allclose(left, np.eye(4))
    cell = default_workcell(
        scale=0.4, offset=(0.0, 0.0, -0.16), pedestal_m=0.0, mounts=(left, right)
    )
    # The block is midway: each arm sees it the same distance in front of it.
    mine = cell.seen_from(left).block.centre
    theirs = cell.seen_from(right).block.centre
    assert np.allclose(mine, theirs) and mine[0] > 0.2
    # A point pushed into the block from the right arm's side is inside it in its frame.
    top = cell.seen_from(right).block
    inside = top.centre + np.array([0.0, 0.0, top.size[2] / 2 - 0.002])
    assert top.penetration(inside)[0] > 0.0
    assert np.allclose(mount_transform(None), np.eye(4))


def test_each_arms_simulated_sensor_samples_at_its_own_share_of_the_period() -> None:
    """Two arms' sensors take turns (phase 0 and ½): woken at the same instant, the
    second queued behind the first for the interpreter (bench.force_under_video)."""
    from telerobot.server.devices import build_arms, build_workcell

    settings = load_settings(arms="left=so101:sim,right=so101:sim", viewer=False)
    arms = build_arms(settings, None, build_workcell(settings))
    assert [getattr(a.force, "phase", None) for a in arms] == [0.0, 0.5]
