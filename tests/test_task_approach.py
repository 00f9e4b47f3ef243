"""Repeating a taught motion from an arm the README's own script moved
(joint 1 turned 0.1 rad: the tool 61 mm / 5.7° from the task's first pose). The
approach is a move in joints, along the line to the first pose's joints, through the
DecisionServer's joint jog (lease, e-stop, dead-man, limits) at the approach's pace;
it is checked before anything moves (reachable, inside the workspace all the way);
an arm that does not follow stops it; the preview gives the approach's way for the
page's ghost. Virtual time on the simulated PUMA, then the REST API in real time."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient

from telerobot.drivers.base import InvalidCommand
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES
from telerobot.drivers.robot.sim import SimPuma
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import LimitExceeded
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.devices import make_kinematics
from telerobot.server.settings import Settings
from telerobot.server.tasks.approach import APPROACH_POINTS, plan_approach
from telerobot.server.tasks.runner import AwayFromStart, Task, TaskRunner, TaskSpec, TaskState
from telerobot.server.tasks.trajectory import StateSample, Trajectory
from tests.support import TOKEN

AUTH = {"Authorization": f"Bearer {TOKEN}"}
README_POINT = np.array([0.6, -0.1, 0.9])  # the README's move_cartesian
JOINT_1_TURN = 0.1  # and its move_joints([0.1, 0, 0, 0, 0, 0], relative=True)
PERIOD = 0.02


def taught_joints() -> np.ndarray:
    """Where the README's move_cartesian leaves the arm from its home (qn): the tool at
    README_POINT, keeping qn's orientation."""
    kin = make_kinematics(Settings())
    T = kin.fk(NAMED_POSES["qn"]).copy()
    T[:3, 3] = README_POINT
    q: np.ndarray = kin.ik(T, NAMED_POSES["qn"])
    return q


def taught_push(q: np.ndarray) -> Trajectory:
    """A 2 cm move down at 2 cm/s taught from joints ``q``, at rest 0.2 s either side."""
    T = make_kinematics(Settings()).fk(q)
    states = []
    for i in range(71):
        t = i * PERIOD
        down = min(max(t - 0.2, 0.0), 1.0) * 0.02
        states.append(StateSample(t, T[:3, 3] - [0.0, 0.0, down], T[:3, :3]))
    return Trajectory.from_samples(states, [], source="taught at the README's pose")


class Cell:
    """The simulated PUMA from ``start`` joints, its DecisionServer (dead-man running)
    and a TaskRunner on one virtual clock; the operator holds the lease."""

    def __init__(self, start: np.ndarray, limits: SafetyLimits | None = None) -> None:
        self.clock = ManualClock()
        settings = Settings()
        limits = limits or SafetyLimits()
        self.robot = SimPuma(
            clock=self.clock, kinematics=make_kinematics(settings), start_joints=start, home=start
        )
        self.decision = DecisionServer(
            [ArmGuard("arm", 1, self.robot, make_kinematics(settings), limits)],
            clock=self.clock,
            operator_token=TOKEN,
            limits=limits,
        )
        self.runner = TaskRunner(self.decision, self.clock, operator_token=TOKEN)
        self.op_id = ""

    async def __aenter__(self) -> Cell:
        await self.robot.connect()
        init = asyncio.ensure_future(self.robot.initialize())  # takes virtual time
        while not init.done():
            await self.clock.advance(0.05)
        init.result()
        self.decision.start()
        self.op_id = self.decision.join("operator", TOKEN).id
        await self.decision.take_lease(self.op_id)
        return self

    async def __aexit__(self, *_exc: object) -> None:
        await self.runner.stop()
        await self.decision.stop()
        await self.robot.disconnect()

    async def advance(self, seconds: float, step: float = 0.005) -> None:
        for _ in range(max(1, round(seconds / step))):
            await self.clock.advance(step)

    async def run(self, task: Task, limit_s: float = 60.0) -> list[np.ndarray]:
        """Let ``task`` run to its end; the commanded joints every period it approached."""
        approach = []
        elapsed = 0.0
        while not task.state.finished:
            assert elapsed < limit_s, f"task still {task.state} after {limit_s} s"
            if task.state is TaskState.APPROACHING:
                approach.append(self.robot.target_joints.copy())
            await self.advance(PERIOD)
            elapsed += PERIOD
        return approach


def readme_start() -> tuple[np.ndarray, np.ndarray]:
    """The taught joints, and the arm after the README's script ran again."""
    q_taught = taught_joints()
    return q_taught, q_taught + [JOINT_1_TURN, 0, 0, 0, 0, 0]


async def test_from_where_the_readme_script_left_the_arm_the_approach_turns_joint_1_back() -> None:
    q_taught, q_now = readme_start()
    path = taught_push(q_taught)
    async with Cell(q_now) as cell:
        # Without the operator's confirmation: refused, saying how far and what to do.
        with pytest.raises(AwayFromStart, match=r"60\.8 mm / 5\.7° .*approach: true"):
            await cell.runner.start(TaskSpec(path), cell.op_id)
        assert cell.decision.lease_holder == cell.op_id

        task = await cell.runner.start(TaskSpec(path, approach=True), cell.op_id)
        assert task.state is TaskState.APPROACHING
        assert cell.decision.lease_holder == task.client_id  # the task's own client moves
        approach = await cell.run(task)
        # It approached and ran to the path's end (before: stopped at once, "too close
        # to a singularity: joint 4 would turn 14.8° for this small move").
        assert task.state is TaskState.DONE, task.reason
        assert np.linalg.norm(cell.robot.pose.position - path.positions[-1]) < 0.005
        # In joints: joint 1 turned back, monotonically, and no other joint turned.
        steps = np.diff(np.array([q_now, *approach, q_taught]), axis=0)
        assert np.max(np.abs(steps[:, 1:])) < 1e-6, np.max(np.abs(steps[:, 1:]))
        assert np.all(steps[:, 0] <= 1e-12)
        # At the approach's pace: the tool's chord per period within 2 cm/s (and the
        # joints within 0.2 rad/s), so 61 mm take about 3 s, not one jump.
        kin = cell.decision.arms[0].kinematics
        tool = np.array([kin.fk(q)[:3, 3] for q in approach])
        chords = np.linalg.norm(np.diff(tool, axis=0), axis=1)
        assert chords.max() <= 0.02 * PERIOD * 1.01, chords.max()
        assert np.abs(steps[:, 0]).max() <= 0.2 * PERIOD * 1.01
        assert len(approach) * PERIOD > 2.5


async def test_the_approach_is_a_move_under_the_safety_checks_the_e_stop_ends_it() -> None:
    q_taught, q_now = readme_start()
    async with Cell(q_now) as cell:
        task = await cell.runner.start(TaskSpec(taught_push(q_taught), approach=True), cell.op_id)
        await cell.advance(1.0)
        assert task.state is TaskState.APPROACHING, task.reason
        turned = q_now[0] - cell.robot.target_joints[0]
        assert math.radians(0.5) < turned < JOINT_1_TURN  # under way, not there yet
        await cell.decision.estop(None, "test")
        await cell.advance(0.1)
        assert task.state is TaskState.STOPPED and "e-stop" in task.reason, task.reason
        assert cell.decision.lease_holder == cell.op_id  # handed back
        held = cell.robot.target_joints.copy()
        await cell.advance(0.5)
        assert np.allclose(cell.robot.target_joints, held)  # nothing moves after it


async def test_an_approach_that_cannot_be_made_is_refused_before_anything_moves() -> None:
    q_taught, q_now = readme_start()
    kin = make_kinematics(Settings())
    # Joint 1 turned 0.5 rad: the tool's arc back to the taught pose bulges out in x.
    q_far = q_taught + [0.5, 0, 0, 0, 0, 0]
    arc = [kin.fk(q_taught + [a, 0, 0, 0, 0, 0])[0, 3] for a in np.linspace(0, 0.5, 51)]
    ends = max(arc[0], arc[-1])
    assert max(arc) > ends + 0.005
    box = SafetyLimits(workspace_max=np.array([ends + 0.002, 0.8, 1.6]))
    async with Cell(q_far, box) as cell:
        with pytest.raises(LimitExceeded, match="outside the workspace"):
            await cell.runner.start(TaskSpec(taught_push(q_taught), approach=True), cell.op_id)
        assert cell.decision.lease_holder == cell.op_id and cell.runner.active is None
    async with Cell(q_now) as cell:
        # A first pose out of the arm's reach (a recording from another cell).
        far = Trajectory.from_samples(
            [StateSample(t, np.array([2.0, 0.0, 0.9]), np.eye(3)) for t in (0.0, 1.0)], []
        )
        with pytest.raises(InvalidCommand, match=r"first pose .* cannot be approached"):
            await cell.runner.start(TaskSpec(far, approach=True), cell.op_id)
        assert cell.decision.lease_holder == cell.op_id and cell.runner.active is None
        assert np.allclose(cell.robot.target_joints, q_now)


async def test_an_arm_that_does_not_follow_the_approach_stops_the_task(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    q_taught, q_now = readme_start()
    async with Cell(q_now) as cell:
        task = await cell.runner.start(TaskSpec(taught_push(q_taught), approach=True), cell.op_id)
        await cell.advance(0.5)
        decision = cell.decision

        async def held(*_args: object, **_kwargs: object) -> None:
            decision.seen(task.client_id)  # the dead-man is fed: only the motion is lost

        monkeypatch.setattr(decision, "joint_increment", held)
        await cell.advance(3.0)
        assert task.state is TaskState.STOPPED, task.reason
        assert task.reason.startswith("the arm did not follow the approach"), task.reason
        assert "no nearer for 2 s" in task.reason


def test_the_approach_ghost_has_at_most_its_cap_of_points() -> None:
    kin = make_kinematics(Settings())
    q0 = NAMED_POSES["qn"]
    far = q0 + [2.0, 0.3, 0, 0, 0, 0]  # joint 1 turns 115°: one point a degree is too many
    T = kin.fk(far)
    plan = plan_approach(
        kin, SafetyLimits(), q0, T[:3, 3], T[:3, :3], tolerance_m=0.001, tolerance_rad=0.01
    )
    assert len(plan.positions) == APPROACH_POINTS
    assert np.allclose(plan.positions[0], kin.fk(q0)[:3, 3])
    assert np.allclose(plan.positions[-1], T[:3, 3], atol=1e-6)


# ------------------------------------------------------------ the REST API
@pytest.fixture
def readme_server() -> Iterator[TestClient]:
    """The app as `make run` starts it (the PUMA at qn), in process, once READY."""
    from telerobot.server.app import create_app

    with TestClient(create_app(Settings(operator_token=TOKEN)), base_url="http://localhost") as tc:
        deadline = time.monotonic() + 10
        while tc.get("/api/v1/robot/state").json()["status"] != "READY":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        yield tc


def test_the_preview_shows_the_approach_and_the_confirmed_task_runs_to_its_end(
    readme_server: TestClient,
) -> None:
    tc = readme_server

    def lease() -> dict[str, str]:
        r = tc.post("/api/v1/lease", json={"name": "readme", "force": True}, headers=AUTH)
        assert r.status_code == 200, r.text
        return {**AUTH, "X-Client-Id": r.json()["client_id"]}

    h = lease()
    to = {"space": "cartesian", "mode": "absolute", "position": README_POINT.tolist()}
    assert tc.post("/api/v1/robot/move", json=to, headers=h).status_code == 200
    assert tc.post("/api/v1/recordings", json={"name": "teach"}, headers=AUTH).status_code == 200
    time.sleep(0.3)  # some states at rest before the move (not a condition)
    down = {"space": "cartesian", "mode": "incremental", "position": [0.0, 0.0, -0.02]}
    assert tc.post("/api/v1/robot/move", json=down, headers=lease()).status_code == 200
    rec = tc.post("/api/v1/recordings/active/stop", headers=AUTH).json()["file"]
    # The README's script again: to its point, then joint 1 turned 0.1 rad.
    h = lease()
    assert tc.post("/api/v1/robot/move", json=to, headers=h).status_code == 200
    q = tc.get("/api/v1/robot/state").json()["target_joints"]
    turn = {"space": "joint", "mode": "absolute", "joints": [q[0] + JOINT_1_TURN, *q[1:]]}
    assert tc.post("/api/v1/robot/move", json=turn, headers=h).status_code == 200
    here = np.array(tc.get("/api/v1/robot/state").json()["position"])

    preview = tc.post("/api/v1/tasks/preview", json={"recording": rec}).json()
    first = np.array(preview["positions"][0])
    assert np.linalg.norm(first - README_POINT) < 0.002
    assert preview["start_distance_m"] == pytest.approx(0.0608, abs=0.002)
    assert math.degrees(preview["start_angle_rad"]) == pytest.approx(5.7, abs=0.1)
    way = np.array(preview["approach"])  # the tool's way there, for the page's ghost
    assert preview["approach_refused"] == "" and 2 <= len(way) <= APPROACH_POINTS
    assert np.linalg.norm(way[0] - here) < 0.001 and np.linalg.norm(way[-1] - first) < 0.001
    # The arc joint 1 draws: every point as far from the base's axis as the ends.
    radius = np.hypot(way[:, 0], way[:, 1])
    assert np.ptp(radius) < 0.001

    h = lease()
    r = tc.post("/api/v1/tasks", json={"recording": rec}, headers=h)
    assert r.status_code == 422 and r.json()["type"].endswith(":away_from_start"), r.text
    r = tc.post("/api/v1/tasks", json={"recording": rec, "approach": True}, headers=h)
    assert r.status_code == 200, r.text
    task = r.json()
    assert task["state"] == "approaching"
    path = tc.get(f"/api/v1/tasks/{task['id']}/path").json()
    assert np.allclose(path["approach"], way, atol=1e-3)
    assert path["start_distance_m"] == pytest.approx(preview["start_distance_m"], abs=1e-3)
    deadline = time.monotonic() + 60
    while True:
        view = tc.get(f"/api/v1/tasks/{task['id']}").json()
        if view["state"] in ("done", "stopped", "aborted"):
            break
        assert time.monotonic() < deadline, view
        time.sleep(0.05)
    assert view["state"] == "done", view
    end = np.array(tc.get("/api/v1/robot/state").json()["position"])
    assert np.linalg.norm(end - (README_POINT - [0, 0, 0.02])) < 0.003
