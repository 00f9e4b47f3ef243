"""The simulated PUMA cell in virtual time, for the task tests and bench.task_replay.

``SimCell``: the simulated arm, force sensor (sampled every millisecond), DecisionServer
(its dead-man and force limit running as in the server) and a TaskRunner on one
ManualClock, with the operator's client holding the lease. ``SimCell.teach_push``: the
operator pushes the tool (pointing down, at mid-block height) along +x into the block's
face nearest the arm at 10 mm/s until the sensor reads ~20 N, holds it 0.5 s and backs
off to where it started, recorded into a Trajectory. ``replay_moved_block``: that push
taught, then repeated by a TaskRunner on a cell whose block moved 5 mm toward the arm,
with compliance along x (``COMPLIANCE``) or position only (None), the unexpected-contact
margin off.
"""

from __future__ import annotations

import asyncio
import dataclasses
import math

import numpy as np

from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.drivers.sim.workcell import Box, Workcell, default_workcell
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.tasks.compliance import ComplianceSettings
from telerobot.server.tasks.runner import Task, TaskRunner, TaskSpec
from telerobot.server.tasks.trajectory import ForceReading, StateSample, Trajectory

TOKEN = "task-replay-operator-token-0123"
DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # tool z pointing down
TAUGHT_N = 20.0
PUSH_SPEED_M_S = 0.01


def moved_block(cell: Workcell, dx: float) -> Workcell:
    """``cell`` with its block moved ``dx`` along x (and in its obstacles)."""
    block = dataclasses.replace(cell.block, centre=cell.block.centre + np.array([dx, 0.0, 0.0]))
    obstacles = tuple(block if b is cell.block else b for b in cell.obstacles)
    return dataclasses.replace(cell, block=block, obstacles=obstacles)


def with_obstacle(cell: Workcell, box: Box) -> Workcell:
    return dataclasses.replace(cell, obstacles=(*cell.obstacles, box))


def push_start(cell: Workcell) -> np.ndarray:
    """Where the push starts: 3 cm in front of the block's face nearest the arm, at
    mid-block height and width."""
    b = cell.block
    return np.array([b.lower[0] - 0.03, b.centre[1], b.centre[2]])


class SimCell:
    """The simulated arm, force sensor, DecisionServer and TaskRunner on one virtual
    clock, with the operator's client holding the lease."""

    def __init__(self, cell: Workcell, start: np.ndarray, *, noise_n: float = 0.02) -> None:
        self.clock = ManualClock()
        self.cell = cell
        kin = Puma560Kinematics(tool_transform(0.1))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = DOWN, start
        self.start_joints = kin.ik(T, NAMED_POSES["qn"])
        self.robot = SimPuma(
            clock=self.clock, kinematics=kin, start_joints=self.start_joints, home=self.start_joints
        )
        self.sensor = SimForceSensor(
            cell,
            self.robot.snapshot,
            Puma560Kinematics(tool_transform(0.1)),
            noise_n=noise_n,
            time_source=self.clock.now,
        )
        self.decision = DecisionServer(
            [
                ArmGuard(
                    "arm",
                    1,
                    self.robot,
                    Puma560Kinematics(tool_transform(0.1)),
                    SafetyLimits(),
                    self.sensor,
                )
            ],
            clock=self.clock,
            operator_token=TOKEN,
        )
        self.runner = TaskRunner(self.decision, self.clock, operator_token=TOKEN)
        self.forces: list[ForceReading] = []
        self.sensor.subscribe(
            lambda s: self.forces.append(ForceReading(s.time, np.array(s.values)))
        )
        self.op_id = ""

    async def setup(self) -> None:
        await self.robot.connect()
        init = asyncio.ensure_future(self.robot.initialize())
        while not init.done():
            await self.clock.advance(0.05)
        init.result()
        self.decision.start()
        self.op_id = self.decision.join("operator", TOKEN).id
        await self.decision.take_lease(self.op_id)

    async def close(self) -> None:
        await self.runner.stop()
        await self.decision.stop()
        await self.robot.disconnect()

    async def advance(self, seconds: float, step: float = 0.001) -> None:
        """Virtual time, the sensor sampled every ``step`` s on the way."""
        for _ in range(max(1, round(seconds / step))):
            await self.clock.advance(step)
            self.sensor.sample_at(self.clock.now())

    def state(self) -> StateSample:
        pose = self.robot.pose
        return StateSample(self.clock.now(), pose.position.copy(), pose.rotation.copy())

    def contact_n(self) -> float:
        sample: ForceSample | None = self.sensor.latest
        return 0.0 if sample is None else math.dist(sample.values[:3], (0.0, 0.0, 0.0))

    async def teach_push(self, force_n: float = TAUGHT_N) -> Trajectory:
        """The operator's push (see the module's text), recorded into a Trajectory."""
        states: list[StateSample] = []
        self.forces.clear()
        ds, period = self.decision, 0.02
        step = np.array([PUSH_SPEED_M_S * period, 0.0, 0.0])

        async def tick(dX: np.ndarray) -> None:
            await ds.cartesian_increment(self.op_id, dX, np.zeros(3))
            await self.advance(period)
            states.append(self.state())

        states.append(self.state())
        for _ in range(4000):  # at most 80 s
            felt = self.contact_n()
            if felt >= force_n:
                break
            await tick(step if felt < 1.0 else step * 0.1)  # in contact: 1 mm/s
        else:
            raise RuntimeError("the push never reached the block")
        for _ in range(25):  # hold 0.5 s
            await tick(np.zeros(3))
        start_x = states[0].position[0]
        while self.robot.pose.position[0] > start_x + 1e-4:  # back off at the same speed
            gap = self.robot.pose.position[0] - start_x
            await tick(-min(gap, step[0]) * np.array([1.0, 0.0, 0.0]))
        for _ in range(10):
            await tick(np.zeros(3))
        return Trajectory.from_samples(states, self.forces, source="taught push")

    async def run(self, spec: TaskSpec, limit_s: float = 60.0) -> Task:
        """Start ``spec`` and let it run to its end; ``forces`` then holds every sample
        the sensor took during the run."""
        self.forces.clear()
        task = await self.runner.start(spec, self.op_id)
        elapsed = 0.0
        while not task.state.finished:
            if elapsed > limit_s:
                raise AssertionError(f"task still {task.state} after {limit_s} s")
            await self.advance(0.02)
            elapsed += 0.02
        return task


COMPLIANCE = ComplianceSettings(axes="x", stiffness_n_per_m=500.0, max_offset_m=0.01)


def peak_n(forces: list[ForceReading]) -> float:
    return max((float(np.linalg.norm(f.values[:3])) for f in forces), default=0.0)


async def replay_moved_block(
    compliance: ComplianceSettings | None,
) -> tuple[Task, float, float]:
    """Teach on the default cell, then repeat with the block 5 mm nearer the arm."""
    base = default_workcell()
    teacher = SimCell(base, push_start(base))
    await teacher.setup()
    try:
        trajectory = await teacher.teach_push()
    finally:
        await teacher.close()
    taught = float(np.max(np.linalg.norm(trajectory.forces, axis=1)))
    cell = SimCell(moved_block(base, -0.005), push_start(base))
    await cell.setup()
    try:
        spec = TaskSpec(trajectory, compliance=compliance, force_margin_n=None)
        task = await cell.run(spec)
        return task, taught, peak_n(cell.forces)
    finally:
        await cell.close()
