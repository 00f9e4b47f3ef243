"""Repeating a taught push with and without compliance.

On the simulation, in virtual time (a ManualClock; the force sensor sampled every
millisecond, the DecisionServer's dead-man and force limit running as in the server):

1. teach: the operator pushes the tool (pointing down, at mid-block height) along +x
   into the block's face nearest the arm at 10 mm/s until the sensor reads ~20 N,
   holds it 0.5 s and backs off to where it started; the states (50 Hz) and forces
   (1 kHz) are the "recording";
2. the block is moved 5 mm toward the arm (−x), and the motion is repeated by a
   TaskRunner twice from the same start: with compliance along x (K 500 N/m) and
   position only. The unexpected-contact margin is off in both runs, so what stops
   the position-only run is the DecisionServer's force limit (60 N).

Figures: ``replay_force_n`` = {"compliance": {peak, mean, limit_tripped},
"position_only": {...}, "taught_n": the peak taught force}. ``peak`` is over every
sensor sample of the repeat; ``mean`` over the task's control periods where the
recording or the repeat had contact (> 2 N).

    python -m bench.task_replay [--json]
"""

from __future__ import annotations

import asyncio
import dataclasses
import math
from typing import Any

import numpy as np

from bench.common import emit, parser
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


def figures(task: Task, peak: float) -> dict[str, Any]:
    """``peak`` from every sensor sample (1 kHz), ``mean`` from the task's periods."""
    contact = [p.force_n for p in task.trace if max(p.recorded_n, p.force_n) > 2.0]
    return {
        "peak": round(peak, 2),
        "mean": round(float(np.mean(contact)), 2) if contact else 0.0,
        "limit_tripped": task.reason.startswith("force limit"),
        "state": str(task.state),
        "reason": task.reason,
    }


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


async def _measure() -> dict[str, Any]:
    compliant, taught, compliant_peak = await replay_moved_block(COMPLIANCE)
    rigid, _, rigid_peak = await replay_moved_block(None)
    return {
        "replay_force_n": {
            "compliance": figures(compliant, compliant_peak),
            "position_only": figures(rigid, rigid_peak),
            "taught_n": round(taught, 2),
        }
    }


def measure() -> dict[str, Any]:
    return asyncio.run(_measure())


def main() -> None:
    args = parser(__doc__ or "").parse_args()
    result = measure()
    r = result["replay_force_n"]
    print(f"taught push: {r['taught_n']} N; block moved 5 mm toward the arm, repeated:")
    for name in ("compliance", "position_only"):
        f = r[name]
        print(
            f"  {name:<14} peak {f['peak']:6.1f} N  mean {f['mean']:6.1f} N  "
            f"force limit tripped: {f['limit_tripped']}  ({f['state']}: {f['reason'] or 'ok'})"
        )
    emit(result, args.json)


if __name__ == "__main__":
    main()
