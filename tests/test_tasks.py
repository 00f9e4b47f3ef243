"""Repeating a taught motion: the trajectory, the admittance law,
and the TaskRunner on the simulation through a real DecisionServer, in virtual time
(the force sensor sampled every millisecond; harness/sim_cell.SimCell)."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest

from harness.sim_cell import (
    COMPLIANCE,
    DOWN,
    SimCell,
    moved_block,
    peak_n,
    push_start,
    replay_moved_block,
    with_obstacle,
)
from telerobot.drivers.base import InvalidCommand
from telerobot.drivers.sim.workcell import Box, default_workcell
from telerobot.server.control.errors import NotAllowed, SafetyStop
from telerobot.server.tasks.compliance import Admittance, ComplianceSettings
from telerobot.server.tasks.runner import TaskSpec, TaskState
from telerobot.server.tasks.trajectory import (
    AnotherArm,
    ForceReading,
    StateSample,
    Trajectory,
    interpolate_rotation,
)


def Rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# ------------------------------------------------------------ trajectory
def test_trajectory_from_samples_resamples_pose_and_force_in_the_base_frame() -> None:
    # 1 s along +x at 0.1 m/s, turning 0.2 rad about z; states at an uneven rate.
    ts = [10.0, 10.3, 10.35, 10.8, 11.0]
    states = [StateSample(t, np.array([0.1 * (t - 10), 0, 0.5]), Rz(0.2 * (t - 10))) for t in ts]
    # The sensor reads 5 N along its own (the tool's) x, which turns with the tool.
    forces = [ForceReading(10 + k * 0.001, np.array([5.0, 0, 0, 0, 0, 0])) for k in range(1001)]
    traj = Trajectory.from_samples(states, forces, dt=0.1)
    assert len(traj) == 11 and traj.duration == pytest.approx(1.0)
    assert traj.positions[:, 0] == pytest.approx(np.linspace(0, 0.1, 11))
    assert traj.rotations[5] == pytest.approx(Rz(0.1), abs=1e-9)
    p, R, f = traj.at(0.25)
    assert p[0] == pytest.approx(0.025)
    assert np.allclose(R, Rz(0.05), atol=1e-9)
    # base = R_tool @ sensor, with the state recorded last before each sample
    assert np.linalg.norm(f) == pytest.approx(5.0, rel=1e-3)
    assert 0.0 < f[1] < 5 * math.sin(0.06)
    assert traj.at(0.9)[2][1] == pytest.approx(5 * math.sin(0.16), abs=1e-3)  # state 10.8
    assert traj.at(99.0)[0] == pytest.approx(traj.positions[-1])  # clamped
    seg = Trajectory.from_samples(states, forces, dt=0.1, segment=(10.3, 10.8))
    assert seg.duration == pytest.approx(0.5) and seg.positions[0][0] == pytest.approx(0.03)
    with pytest.raises(InvalidCommand, match="two robot states"):
        Trajectory.from_samples(states[:1], forces)
    with pytest.raises(InvalidCommand, match="segment"):
        Trajectory.from_samples(states, forces, segment=(11.0, 10.0))


def test_trajectory_from_recording_messages_keeps_one_episode() -> None:
    msgs: list[tuple[str, dict[str, object]]] = []
    for k in range(100):  # 2 s of states; episode 1 from 0.5 s to 1.5 s
        t = k * 0.02
        if k == 25:
            msgs.append(("/episodes", {"t": t, "event": "start", "episode": 1}))
        if k == 75:
            msgs.append(("/episodes", {"t": t, "event": "end", "episode": 1}))
        rot = np.eye(3).reshape(9).tolist()
        msgs.append(("/robot/state", {"t": t, "position": [t, 0, 0.5], "rotation": rot}))
        msgs.append(("/force", {"t": t, "values": [0, 0, 3.0, 0, 0, 0]}))
    traj = Trajectory.from_messages(msgs, episode=1)
    assert traj.positions[0][0] == pytest.approx(0.5) and traj.duration == pytest.approx(1.0)
    assert traj.forces[3] == pytest.approx([0, 0, 3.0])
    seg = Trajectory.from_messages(msgs, episode=1, segment=(0.2, 0.4))
    assert seg.positions[0][0] == pytest.approx(0.7) and seg.duration == pytest.approx(0.2)
    with pytest.raises(InvalidCommand, match="no episode 7"):
        Trajectory.from_messages(msgs, episode=7)


def test_a_recording_of_another_arm_model_is_refused_at_its_settings() -> None:
    """A PUMA 560's recording on an SO-101 server is refused, saying
    which arm made it and which this server drives, at its first message (/settings),
    before any state is read; the same model's, or one that does not say, is read."""
    rot = np.eye(3).reshape(9).tolist()
    Messages = list[tuple[str, dict[str, object]]]
    states: Messages = [
        ("/robot/state", {"t": k * 0.02, "position": [0.5, 0, 0.5], "rotation": rot})
        for k in range(10)
    ]
    puma: Messages = [("/settings", {"robot_model": "puma560", "robot": "sim"}), *states]
    with pytest.raises(
        AnotherArm, match=r"another arm model \(puma560\) than this server's \(so101\)"
    ) as e:
        Trajectory.from_messages(puma, robot_model="so101", source="teach.mcap episode 0")
    assert e.value.code == "another_arm" and str(e.value).startswith("teach.mcap episode 0 ")

    def no_states() -> Iterator[tuple[str, dict[str, object]]]:
        yield puma[0]
        raise AssertionError("read past the recording's settings")

    with pytest.raises(AnotherArm):
        Trajectory.from_messages(no_states(), robot_model="so101")
    n = len(Trajectory.from_messages(states))
    assert n > 2 and len(Trajectory.from_messages(puma, robot_model="puma560")) == n
    assert len(Trajectory.from_messages(puma)) == n  # no model asked: any
    assert len(Trajectory.from_messages(states, robot_model="so101")) == n  # it does not say


def test_rotation_interpolation_takes_the_short_arc() -> None:
    assert interpolate_rotation(Rz(0.0), Rz(1.0), 0.5) == pytest.approx(Rz(0.5), abs=1e-12)
    assert interpolate_rotation(Rz(3.0), Rz(-3.0), 0.5) == pytest.approx(Rz(math.pi), abs=1e-9)


# ------------------------------------------------------------ compliance
def test_admittance_settles_at_force_error_over_stiffness_on_chosen_axes() -> None:
    law = Admittance(ComplianceSettings(axes="x", stiffness_n_per_m=1000, max_rate_m_s=0.1))
    for _ in range(2000):
        law.step(np.array([-25.0, 7.0, 0]), np.array([-20.0, 0, 0]), 0.01)
    assert law.offset == pytest.approx([-0.005, 0, 0], abs=1e-6)  # y is not a chosen axis


def test_admittance_is_rate_and_range_limited() -> None:
    s = ComplianceSettings(axes="xyz", stiffness_n_per_m=100, max_offset_m=0.004, max_rate_m_s=0.01)
    law = Admittance(s)
    out = law.step(np.array([0, 0, 100.0]), np.zeros(3), 0.02)  # target 1 m away
    assert out[2] == pytest.approx(0.0002)  # 10 mm/s for 20 ms
    for _ in range(1000):
        out = law.step(np.array([0, 0, 100.0]), np.zeros(3), 0.02)
    assert out[2] == pytest.approx(0.004)  # never beyond the range
    assert law.step(np.array([np.nan, 0, 0]), np.zeros(3), 0.02)[0] == 0.0  # bad sample
    with pytest.raises(InvalidCommand):
        ComplianceSettings(axes="xw")
    with pytest.raises(InvalidCommand):
        ComplianceSettings(max_offset_m=1.0)


# ------------------------------------------------------------ the runner on the simulation
@pytest.fixture
async def taught() -> Trajectory:
    base = default_workcell()
    cell = SimCell(base, push_start(base))
    await cell.setup()
    try:
        return await cell.teach_push()
    finally:
        await cell.close()


async def cell_for(work: object = None) -> SimCell:
    base = default_workcell()
    cell = SimCell(base if work is None else work, push_start(base))  # type: ignore[arg-type]
    await cell.setup()
    return cell


async def test_a_task_repeats_the_push_to_its_end_and_hands_the_lease_back(
    taught: Trajectory,
) -> None:
    assert 19.0 < float(np.max(np.linalg.norm(taught.forces, axis=1))) < 25.0
    cell = await cell_for()
    try:
        task = await cell.run(TaskSpec(taught, compliance=COMPLIANCE))
        assert task.state is TaskState.DONE, task.reason
        assert task.status().progress == 1.0
        assert 18.0 < task.peak_force_n < 26.0  # the same push, the same force
        end = taught.positions[-1]
        assert np.linalg.norm(cell.robot.pose.position - end) < 0.002
        assert cell.decision.lease_holder == cell.op_id  # handed back
    finally:
        await cell.close()


async def test_pause_resume_and_abort(taught: Trajectory) -> None:
    cell = await cell_for()
    try:
        task = await cell.runner.start(TaskSpec(taught), cell.op_id)
        assert cell.decision.lease_holder == task.client_id
        with pytest.raises(NotAllowed, match="lease"):  # the task holds it now
            await cell.runner.start(TaskSpec(taught), cell.op_id)
        await cell.advance(0.5)
        cell.runner.pause(task.id, cell.op_id)
        await cell.advance(0.1)
        held_s, held_at = task.s, cell.robot.pose.position.copy()
        await cell.advance(1.0)  # paused: no progress, the arm holds, the dead-man is fed
        assert task.state is TaskState.PAUSED and task.s == held_s
        assert np.linalg.norm(cell.robot.pose.position - held_at) < 1e-4
        assert cell.decision.lease_holder == task.client_id
        cell.runner.resume(task.id, cell.op_id)
        await cell.advance(0.5)
        assert task.s > held_s
        await cell.runner.abort(task.id, cell.op_id)
        assert task.state is TaskState.ABORTED and "operator" in task.reason
        moved = task.s
        await cell.advance(0.5)
        assert task.s == moved and cell.decision.lease_holder == cell.op_id
        with pytest.raises(InvalidCommand):
            cell.runner.resume(task.id, cell.op_id)
    finally:
        await cell.close()


async def test_e_stop_stops_the_task(taught: Trajectory) -> None:
    cell = await cell_for()
    try:
        task = await cell.runner.start(TaskSpec(taught), cell.op_id)
        await cell.advance(0.5)
        await cell.decision.estop(None, "test")
        await cell.advance(0.1)
        assert task.state is TaskState.STOPPED and "e-stop" in task.reason
        s = task.s
        await cell.advance(0.5)
        assert task.s == s
    finally:
        await cell.close()


async def test_losing_the_lease_stops_the_task(taught: Trajectory) -> None:
    cell = await cell_for()
    try:
        task = await cell.runner.start(TaskSpec(taught), cell.op_id)
        await cell.advance(0.5)
        other = cell.decision.join("another operator", "task-replay-operator-token-0123")
        await cell.decision.take_lease(other.id, force=True)
        await cell.advance(0.1)
        assert task.state is TaskState.STOPPED and "lease lost" in task.reason
        assert cell.decision.lease_holder == other.id  # not handed back over the new holder
    finally:
        await cell.close()


async def test_a_task_needs_the_lease_and_a_start_near_its_first_pose(taught: Trajectory) -> None:
    cell = await cell_for()
    try:
        observer = cell.decision.join("observer", None)
        with pytest.raises(NotAllowed):
            await cell.runner.start(TaskSpec(taught), observer.id)
        await cell.decision.cartesian_increment(cell.op_id, np.array([0, 0.015, 0]), np.zeros(3))
        await cell.advance(0.5)
        with pytest.raises(InvalidCommand, match="first pose"):
            await cell.runner.start(TaskSpec(taught), cell.op_id)
        assert cell.decision.lease_holder == cell.op_id
        # Confirmed: a guarded approach, then the task.
        task = await cell.run(TaskSpec(taught, approach=True))
        assert task.state is TaskState.DONE, task.reason
        await cell.decision.estop(None, "test")
        with pytest.raises(SafetyStop):
            await cell.runner.start(TaskSpec(taught, approach=True), cell.op_id)
    finally:
        await cell.close()


async def test_an_unexpected_contact_stops_the_task_by_the_margin(taught: Trajectory) -> None:
    # A box across the path, 1 cm before the block: not in the recording.
    base = default_workcell()
    start = push_start(base)
    wall = Box(
        "obstacle",
        centre=np.array([start[0] + 0.015, start[1], start[2]]),
        size=np.array([0.004, 0.05, 0.05]),
        colour=(0, 0, 0),
        stiffness=5.0e4,
        damping=80.0,
    )
    cell = await cell_for(with_obstacle(base, wall))
    try:
        task = await cell.run(TaskSpec(taught, force_margin_n=10.0))
        assert task.state is TaskState.STOPPED and "unexpected contact" in task.reason
        assert peak_n(cell.forces) < cell.decision.limits.force_limit_n  # before the limit
        assert not cell.decision.state().force_limited
        assert cell.robot.pose.position[0] < wall.lower[0] + 0.002
    finally:
        await cell.close()


async def test_moved_block_compliance_keeps_the_taught_force_position_only_trips() -> None:
    compliant, taught_n, compliant_peak = await replay_moved_block(COMPLIANCE)
    rigid, _, rigid_peak = await replay_moved_block(None)
    assert 19.0 < taught_n < 25.0
    assert compliant.state is TaskState.DONE, compliant.reason
    assert compliant_peak < taught_n + 10.0  # near the taught force: no trip
    assert rigid.state is TaskState.STOPPED and rigid.reason.startswith("force limit")
    assert rigid_peak > 60.0


def test_a_task_spec_checks_its_speed_and_margin(taught_free: None = None) -> None:
    states = [StateSample(t, np.array([0.5, 0, 0.5]), DOWN) for t in (0.0, 1.0)]
    traj = Trajectory.from_samples(states, [])
    with pytest.raises(InvalidCommand, match=r"0\.1–1"):
        TaskSpec(traj, speed=2.0)
    with pytest.raises(InvalidCommand, match="force_margin_n"):
        TaskSpec(traj, force_margin_n=0.0)
    assert moved_block(default_workcell(), -0.005).block.lower[0] == pytest.approx(0.595)
