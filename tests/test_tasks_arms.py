"""A task from a two-arm recording (docs/tasks.md), in virtual time: each recorded arm's
path read by its name on one grid, a recording of other arms refused by name; the
TaskRunner repeating both arms' paths together through a real two-arm DecisionServer
(each command naming its arm), each arm under its own force guard: a contact on one arm
stops the task, and the reason names the arm."""

from __future__ import annotations

import math
import re
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass

import numpy as np
import pytest

from telerobot.drivers.base import ForceSample, InvalidCommand
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.puma560.kinematics import (
    Puma560Kinematics,
    tool_transform,
)
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.tasks.runner import Task, TaskRunner, TaskSpec, TaskState
from telerobot.server.tasks.trajectory import (
    AnotherArm,
    OtherArms,
    StateSample,
    Trajectory,
    read_paths,
)
from tests.support import TOKEN
from tests.support.decision import RecordingPuma, recording_puma

ROT = np.eye(3).reshape(9).tolist()
Messages = list[tuple[str, dict[str, object]]]


# ------------------------------------------------------------ reading each arm's path
def two_arm_messages(models: tuple[str, str] = ("so101", "so101")) -> Messages:
    """A two-arm recording's messages: /settings naming left and right, 2 s of each
    arm's states (left along +x, right along +y; the right's logged 1 ms after the
    left's) and forces, and episode 0 from 0.5 s to 1.5 s."""
    settings = {
        "robot_model": "puma560",  # the server's own: each arm's model is its own
        "arms": {"left": {"robot_model": models[0]}, "right": {"robot_model": models[1]}},
    }
    msgs: Messages = [("/settings", settings)]
    for k in range(101):
        t = 10.0 + k * 0.02
        if k == 25:
            msgs.append(("/episodes", {"t": t, "event": "start", "episode": 0}))
        if k == 75:
            msgs.append(("/episodes", {"t": t, "event": "end", "episode": 0}))
        s = t - 10.0
        left = {"t": t, "arm": "left", "position": [s, 0, 0.5], "rotation": ROT}
        right = {"t": t + 0.001, "arm": "right", "position": [0, s, 0.5], "rotation": ROT}
        msgs.append(("/arms/left/state", left))
        msgs.append(("/arms/right/state", right))
        msgs.append(("/arms/left/force", {"t": t, "values": [0, 0, 1.0, 0, 0, 0]}))
        msgs.append(("/arms/right/force", {"t": t, "values": [0, 0, 4.0, 0, 0, 0]}))
    return msgs


def test_each_recorded_arm_s_path_is_read_by_its_name_on_one_grid() -> None:
    paths = read_paths(
        two_arm_messages(), episode=0, arm_models={"left": "so101", "right": "so101"}
    )
    assert list(paths) == ["left", "right"]
    left, right = paths["left"], paths["right"]
    assert len(left) == len(right) and left.duration == pytest.approx(1.0, abs=0.021)
    # Each its own path and forces, on the same instants (one path clock drives both).
    assert left.positions[0] == pytest.approx([0.501, 0, 0.5], abs=0.002)
    assert right.positions[0] == pytest.approx([0, 0.501, 0.5], abs=0.002)
    assert left.positions[-1][0] - left.positions[0][0] == pytest.approx(right.duration, abs=0.021)
    assert left.forces[5] == pytest.approx([0, 0, 1.0]) and right.forces[5] == pytest.approx(
        [0, 0, 4.0]
    )
    with pytest.raises(OtherArms, match="read_paths"):  # the one-arm reader says why not
        Trajectory.from_messages(two_arm_messages(), episode=0)


def test_a_recording_is_repeated_only_on_arms_of_its_arms_names_and_models() -> None:
    two = {"left": "so101", "right": "so101"}
    with pytest.raises(OtherArms, match=r"2 arms \(left, right\), and this server drives one arm"):
        read_paths(two_arm_messages(), arm_models={"arm": "so101"}, source="two.mcap")
    with pytest.raises(AnotherArm, match=r"its arm 'right' was recorded as another arm model"):
        read_paths(two_arm_messages(("so101", "puma560")), arm_models=two)
    one_arm: Messages = [
        ("/settings", {"robot_model": "so101"}),
        *(
            ("/robot/state", {"t": k * 0.02, "position": [0.3, 0, 0.2], "rotation": ROT})
            for k in range(10)
        ),
    ]
    with pytest.raises(OtherArms, match=r"with one arm, and this server drives 2 arms"):
        read_paths(one_arm, arm_models=two, source="one.mcap")
    # A one-arm recording on a one-arm server, as before: its one path, named "arm".
    assert list(read_paths(one_arm, arm_models={"arm": "so101"})) == ["arm"]
    # A recording whose /settings were not kept: its arms' channels name them.
    assert list(read_paths(two_arm_messages()[1:], arm_models=two)) == ["left", "right"]
    with pytest.raises(OtherArms):
        read_paths(two_arm_messages()[1:], arm_models={"left": "so101"})


def test_an_arm_without_states_in_the_span_is_refused_by_name() -> None:
    msgs = [m for m in two_arm_messages() if m[0] != "/arms/right/state"]
    with pytest.raises(InvalidCommand, match="two robot states of its arm 'right'"):
        read_paths(msgs, episode=0)


# ------------------------------------------------------------ repeating both arms
class PushedSensor:
    """A force sensor whose reading the test sets: the DecisionServer hears it (its force
    limit) and the task reads it (its margin), as a real sensor's."""

    name = "pushed"
    rate_hz = 1000.0
    threshold = 0.0
    filter_cutoff_hz = None

    def __init__(self) -> None:
        self.latest: ForceSample | None = None
        self.seq = 0
        self._subscribers: list[Callable[[ForceSample], None]] = []

    def subscribe(
        self, callback: Callable[[ForceSample], None], *, first: bool = False
    ) -> Callable[[], None]:
        self._subscribers.append(callback)
        return lambda: self._subscribers.remove(callback)

    def push(self, t: float, fz: float) -> None:
        self.seq += 1
        self.latest = ForceSample(self.seq, t, (0.0, 0.0, fz, 0.0, 0.0, 0.0))
        for callback in list(self._subscribers):
            callback(self.latest)


@dataclass
class TwoArmCell:
    clock: ManualClock
    decision: DecisionServer
    runner: TaskRunner
    robots: dict[str, RecordingPuma]
    sensors: dict[str, PushedSensor]
    op_id: str

    async def run(
        self, task: Task, limit_s: float = 30.0, during: Callable[[], None] = list
    ) -> None:
        elapsed = 0.0
        while not task.state.finished:
            assert elapsed < limit_s, f"task still {task.state} after {limit_s} s"
            for _ in range(20):
                await self.clock.advance(0.001)
            elapsed += 0.02
            during()


def moving_path(start: np.ndarray, rotation: np.ndarray, direction: np.ndarray) -> Trajectory:
    """From ``start``, 3 cm along ``direction`` in 1 s (states at 50 Hz, as recorded)."""
    states = [
        StateSample(0.02 * k, start + direction * 0.03 * min(k / 50, 1.0), rotation)
        for k in range(61)
    ]
    return Trajectory.from_samples(states, [], source="taught with two arms")


@pytest.fixture
async def cell() -> AsyncIterator[TwoArmCell]:
    clock = ManualClock()
    robots, sensors = {}, {}
    for name in ("left", "right"):
        robots[name], sensors[name] = await recording_puma(clock), PushedSensor()
    limits = SafetyLimits()
    decision = DecisionServer(
        [
            ArmGuard(
                name,
                i + 1,
                robots[name],
                Puma560Kinematics(tool_transform(0.1)),
                limits,
                sensors[name],  # type: ignore[arg-type]
            )
            for i, name in enumerate(("left", "right"))
        ],
        clock=clock,
        operator_token=TOKEN,
        limits=limits,
    )

    decision.start()
    runner = TaskRunner(decision, clock, operator_token=TOKEN)
    op = decision.join("operator", TOKEN)
    await decision.take_lease(op.id)
    yield TwoArmCell(clock, decision, runner, robots, sensors, op.id)
    await runner.stop()
    await decision.stop()


def both_paths(cell: TwoArmCell) -> dict[str, Trajectory]:
    """The left arm's tool 3 cm along +x, the right's along +y, from where each is."""
    out = {}
    for name, direction in (("left", [1.0, 0, 0]), ("right", [0, 1.0, 0])):
        pose = cell.robots[name].pose
        out[name] = moving_path(pose.position.copy(), pose.rotation.copy(), np.array(direction))
    return out


async def test_a_two_arm_task_repeats_both_arms_paths_together(cell: TwoArmCell) -> None:
    paths = both_paths(cell)
    task = await cell.runner.start(TaskSpec.of_paths(paths), cell.op_id)
    assert [run.name for run in task.runs] == ["left", "right"]
    assert task.status().arms == ("left", "right")
    worst = {"left": 0.0, "right": 0.0}

    def follows() -> None:  # every period: each arm near its own path's point now
        for name, path in paths.items():
            p, _, _ = path.at(task.s)
            gap = float(np.linalg.norm(cell.robots[name].pose.position - p))
            worst[name] = max(worst[name], gap)

    await cell.run(task, during=follows)
    assert task.state is TaskState.DONE, task.reason
    for name, path in paths.items():
        end = path.positions[-1]
        assert np.linalg.norm(cell.robots[name].pose.position - end) < 0.005, name
        assert cell.robots[name].sent, f"{name} was never commanded"
    # Together: neither arm ran ahead of the one path clock (the hold gap is 10 mm).
    assert max(worst.values()) < 0.012, worst
    assert cell.decision.lease_holder == cell.op_id  # handed back


@pytest.mark.parametrize(
    ("push_n", "reason"),
    [
        (20.0, r"^right: unexpected contact: 20\.0 N where 0\.0 N was taught"),
        (100.0, r"^force limit reached on right \(60 N\)"),
    ],
)
async def test_a_contact_on_one_arm_stops_the_task_and_names_that_arm(
    cell: TwoArmCell, push_n: float, reason: str
) -> None:
    task = await cell.runner.start(TaskSpec.of_paths(both_paths(cell)), cell.op_id)
    await _advance(cell, 0.2)  # a fifth of the way along
    assert task.state is TaskState.RUNNING and 0.1 < task.s < 0.3
    cell.sensors["right"].push(cell.clock.now(), push_n)  # the right arm meets something
    await cell.run(task, limit_s=1.0)
    assert task.state is TaskState.STOPPED
    assert re.search(reason, task.reason), task.reason
    assert cell.decision.lease_holder == cell.op_id
    moved = {name: len(robot.sent) for name, robot in cell.robots.items()}
    await _advance(cell, 0.2)
    assert {name: len(robot.sent) for name, robot in cell.robots.items()} == moved  # both still


async def _advance(cell: TwoArmCell, seconds: float) -> None:
    for _ in range(round(seconds / 0.001)):
        await cell.clock.advance(0.001)


async def test_a_one_arm_task_on_a_two_arm_server_is_refused_and_moves_nothing(
    cell: TwoArmCell,
) -> None:
    path = both_paths(cell)["left"]
    with pytest.raises(InvalidCommand, match=r"drives 2 arms \(left, right\): name the arm"):
        await cell.runner.start(TaskSpec(path), cell.op_id)
    with pytest.raises(InvalidCommand, match=r"no arm named 'middle'"):
        await cell.runner.start(TaskSpec.of_paths({"left": path, "middle": path}), cell.op_id)
    assert cell.decision.lease_holder == cell.op_id and cell.runner.active is None
    assert not cell.robots["left"].sent and not cell.robots["right"].sent


async def test_both_arms_approach_their_first_poses_before_the_paths_run(
    cell: TwoArmCell,
) -> None:
    paths = both_paths(cell)
    away = {"left": np.array([0.0, 0.0, 0.03]), "right": np.array([0.0, 0.0, -0.02])}
    for name, offset in away.items():  # each tool moved away from its path's start
        robot = cell.robots[name]
        for _ in range(6):
            await cell.decision.cartesian_increment(cell.op_id, offset / 6, np.zeros(3), arm=name)
            await _advance(cell, 0.1)
        assert np.linalg.norm(robot.pose.position - paths[name].positions[0]) > 0.015
    task = await cell.runner.start(TaskSpec.of_paths(paths, approach=True), cell.op_id)
    assert task.state is TaskState.APPROACHING
    assert all(run.approach is not None for run in task.runs)
    await cell.run(task)
    assert task.state is TaskState.DONE, task.reason
    for name, path in paths.items():
        assert np.linalg.norm(cell.robots[name].pose.position - path.positions[-1]) < 0.005


def test_a_one_arm_recording_s_spec_is_as_before() -> None:
    path = moving_path(np.array([0.5, 0, 0.5]), np.eye(3), np.array([1.0, 0, 0]))
    spec = TaskSpec.of_paths({"arm": path})
    assert spec.arm_paths == () and spec.trajectory is path and spec.paths == [(None, path)]
    assert math.isclose(spec.duration, path.duration)
