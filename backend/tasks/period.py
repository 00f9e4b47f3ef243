"""One period of a running task: the TaskRunner's loop (runner.py) asks, every
``period_s``, why the task must stop (``guard``) and then takes one ``step``: each
arm's forces against those taught near that point, the path's clock (it waits for an
arm behind, and a wait that gains nothing stops the task), and each arm's command, a
Cartesian increment towards the path's point (or, approaching, a joint increment
towards its first pose) through the DecisionServer like any client's. At the path's
end, ``short_of_end`` says how far a tool came from it.

Apart from runner.py, which starts, pauses and ends tasks and hands the lease to and
fro: this is what one period does, whoever runs the loop."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, TelerobotError, WorkingFrame
from telerobot.drivers.clock import Clock
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed, SafetyStop
from telerobot.server.tasks.approach import approach_step
from telerobot.server.tasks.task import ArmRefused, ArmRun, Task, TaskState, TracePoint
from telerobot.server.tasks.trajectory import Trajectory


def distance_to(position: FloatArray, rotation: FloatArray, guard: ArmGuard) -> tuple[float, float]:
    """How far ``guard``'s arm's tool is from the pose (m, rad)."""
    pose = guard.robot.pose
    angle = float(np.linalg.norm(pin.log3(pose.rotation.T @ rotation)))
    return float(np.linalg.norm(pose.position - position)), angle


def distance_to_start(trajectory: Trajectory, guard: ArmGuard) -> tuple[float, float]:
    """How far ``guard``'s arm's tool is from the trajectory's first pose (m, rad)."""
    p0, R0, _ = trajectory.at(0.0)
    return distance_to(p0, R0, guard)


class TaskPeriod:
    def __init__(
        self, decision: DecisionServer, clock: Clock, changed: Callable[[Task], None]
    ) -> None:
        """``changed``: said when a task's state changes here (its approach ends)."""
        self.decision = decision
        self.clock = clock
        self.changed = changed

    def guard(self, task: Task) -> str | None:
        """Why the task must stop now, or None."""
        decision = self.decision
        state = decision.state()
        if state.estop:
            return f"e-stop ({state.estop_reason})"
        if decision.lease_holder != task.client_id:
            return f"lease lost ({state.lease_note or 'control changed hands'})"
        if state.force_limited:
            if len(decision.arms) == 1:
                return f"force limit ({decision.limits.force_limit_n:g} N) reached"
            # Any arm's: an arm the task does not move was pushed (by one it moves?).
            limited = [decision.arm(name) for name in state.force_limited_arms]
            return "force limit reached on " + ", ".join(
                f"{guard.name} ({guard.limits.force_limit_n:g} N)" for guard in limited
            )
        try:
            decision.clients.get(task.supervisor_id)
        except NotAllowed:
            return (
                f"the supervising operator {task.supervisor_name!r} disconnected (a page:"
                " its connection closed; a script: it released its lease, or sent no"
                " request or heartbeat for the server's rest_client_idle_s)"
            )
        return None

    async def step(self, task: Task, dt: float) -> bool:
        """One period: advance along the path, check the margins, command each arm's
        pose. True once the path's end has been commanded."""
        spec = task.spec
        for run in task.runs:
            run.measured = self._measured_force(run)
            run.force_n = float(np.linalg.norm(run.measured))
        strongest = max(task.runs, key=lambda run: run.force_n)
        task.force_n = strongest.force_n
        task.peak_force_n = max(task.peak_force_n, task.force_n)
        if task.state is TaskState.APPROACHING:
            for run in task.runs:
                self._check_margin(
                    task, run, run.trajectory.peak_force_near(0.0, spec.margin_window_s)
                )
            await self._approach(task, dt)
            return False
        if task.state is TaskState.RUNNING:
            self._advance(task, dt)
        targets = []
        for run in task.runs:
            p, R, recorded = run.trajectory.at(task.s)
            run.recorded_n = float(np.linalg.norm(recorded))
            self._check_margin(
                task, run, run.trajectory.peak_force_near(task.s, spec.margin_window_s)
            )
            if run.admittance is not None:
                p = p + run.admittance.step(run.measured, recorded, dt)
            targets.append((run, p, R))
        task.recorded_n = strongest.recorded_n
        offset = task.admittance.offset if task.admittance is not None else np.zeros(3)
        task.trace.append(
            TracePoint(
                self.clock.now(),
                task.s,
                task.force_n,
                task.recorded_n,
                (float(offset[0]), float(offset[1]), float(offset[2])),
            )
        )
        for run, p, R in targets:
            await self._command_towards(task, run, p, R, None)
        return task.s >= spec.duration and not self._behind(task)

    def short_of_end(self, task: Task, arrived: bool, settle_s: float) -> str:
        """Why the task is not done though its path's end was commanded ("" if every
        arm's tool is at its end, within the tolerance)."""
        spec = task.spec
        for run in task.runs:
            traj = run.trajectory
            p, R, _ = traj.at(traj.duration)
            if run.admittance is not None:
                p = p + run.admittance.offset
            pose = run.guard.robot.pose
            distance = float(np.linalg.norm(pose.position - p))
            angle = float(np.linalg.norm(pin.log3(pose.rotation.T @ R)))
            if distance <= spec.end_tolerance_m and angle <= spec.end_tolerance_rad:
                continue
            where = f"{distance * 1000:.0f} mm / {math.degrees(angle):.1f}° from it"
            when = (
                f"came to rest {where}"
                if arrived
                else f"was still {where} {settle_s:g} s after it was sent there"
            )
            return run.said(
                f"did not reach the path's end: the tool {when} (done is within "
                f"{spec.end_tolerance_m * 1000:.0f} mm / "
                f"{math.degrees(spec.end_tolerance_rad):.0f}°)"
            )
        return ""

    def _advance(self, task: Task, dt: float) -> None:
        """The path's clock: it runs while every arm keeps up and waits while a
        commanded target is behind; a wait that gains nothing for ``stall_s`` ends it."""
        spec = task.spec
        if not self._behind(task):
            task.s = min(task.s + dt * spec.speed, spec.duration)
            task.held_gap, task.held_since = math.inf, None
            return
        now = self.clock.now()
        # Progress while waiting: a millimetre, or a tenth of a degree (as metres).
        gap = task.gap_m + task.gap_rad * 0.001 / math.radians(0.1)
        if task.held_since is None or gap < task.held_gap - 0.001:
            task.held_gap, task.held_since = gap, now
        elif now - task.held_since > spec.stall_s:
            worst = max(task.runs, key=lambda run: run.gap_m + run.gap_rad)
            raise SafetyStop(
                worst.said(
                    f"the arm could not follow the path: {worst.gap_m * 1000:.0f} mm / "
                    f"{math.degrees(worst.gap_rad):.1f}° behind it at s = {task.s:.2f} s, and no "
                    f"closer for {spec.stall_s:g} s"
                )
            )

    def _measured_force(self, run: ArmRun) -> FloatArray:
        """The arm's newest contact force (x, y, z) in its base frame."""
        sample = run.force.latest if run.force is not None else None
        if sample is None:
            return np.zeros(3)
        f = np.asarray(sample.values[:3], dtype=float)
        result: FloatArray = run.guard.robot.pose.rotation @ f
        return result

    async def _approach(self, task: Task, dt: float) -> None:
        """One period of the approach: each arm not yet there takes a joint increment
        along the line to its first pose's joints (the DecisionServer's checks, as every
        joint jog), until its tool is within half the start's tolerance; RUNNING once
        every arm is. An arm that gets no nearer for ``stall_s`` stops the task, saying
        how far it still was."""
        for run in task.runs:
            if not run.approached:
                await self._approach_arm(task, run, dt)
        if all(run.approached for run in task.runs):
            task.state = TaskState.RUNNING
            task.held_gap, task.held_since = math.inf, None
            self.changed(task)

    async def _approach_arm(self, task: Task, run: ArmRun, dt: float) -> None:
        spec, plan, guard = task.spec, run.approach, run.guard
        assert plan is not None  # not approached only with a plan (start)
        lim = guard.limits
        dq = approach_step(
            guard.kinematics,
            guard.robot.target_joints,
            plan.goal,
            dt,
            joint_speed_rad_s=min(spec.approach_joint_speed_rad_s, lim.max_joint_speed_rad_s),
            tool_speed_m_s=min(spec.approach_speed_m_s, lim.max_speed_m_s),
            max_step_rad=lim.max_joint_step_rad * 0.99,
        )
        try:
            if run.named:
                await self.decision.joint_increment(task.client_id, dq, arm=run.name)
            else:  # (the only arm: named in no command, as a one-arm task's always were)
                await self.decision.joint_increment(task.client_id, dq)
        except TelerobotError as exc:
            raise self._refused(run, exc) from exc
        distance, angle = distance_to_start(run.trajectory, guard)
        if distance <= spec.start_tolerance_m / 2 and angle <= spec.start_tolerance_rad / 2:
            run.approached = True
            return
        # The measured joints' way still to go: it shrinks while the arm follows.
        gap = float(np.max(np.abs(plan.goal - guard.robot.joints)))
        now = self.clock.now()
        if run.held_since is None or gap < run.held_gap - math.radians(0.1):
            run.held_gap, run.held_since = gap, now
        elif now - run.held_since > spec.stall_s:
            raise SafetyStop(
                run.said(
                    f"the arm did not follow the approach: still {distance * 1000:.0f} mm / "
                    f"{math.degrees(angle):.1f}° from the task's first pose (a joint "
                    f"{math.degrees(gap):.1f}° from it), and no nearer for {spec.stall_s:g} s"
                )
            )

    @staticmethod
    def _behind(task: Task) -> bool:
        """A commanded target is too far behind the path's point for the path's clock
        to run on."""
        spec = task.spec
        return task.gap_m > spec.hold_gap_m or task.gap_rad > spec.hold_gap_rad

    @staticmethod
    def _check_margin(task: Task, run: ArmRun, recorded_n: float) -> None:
        margin = task.spec.force_margin_n
        if margin is not None and run.force_n > recorded_n + margin:
            raise SafetyStop(
                run.said(
                    f"unexpected contact: {run.force_n:.1f} N where {recorded_n:.1f} N was "
                    f"taught near this point (margin {margin:g} N)"
                )
            )

    @staticmethod
    def _refused(run: ArmRun, exc: TelerobotError) -> TelerobotError:
        """A command's refusal, naming the arm (a multi-arm task's) if it does not."""
        if not run.named or str(exc).startswith(f"{run.name}: "):
            return exc
        return ArmRefused(run.said(str(exc)))

    async def _command_towards(
        self, task: Task, run: ArmRun, p: FloatArray, R: FloatArray, max_step: float | None
    ) -> None:
        """One Cartesian increment (the arm's base frame) from its commanded target
        toward (p, R), within the per-command step limits (the DecisionServer's speed
        limit paces it further)."""
        decision, guard = self.decision, run.guard
        T0 = guard.kinematics.fk(guard.robot.target_joints)
        dX = p - T0[:3, 3]
        rv = pin.log3(R @ T0[:3, :3].T)
        lim = guard.limits
        cap = lim.max_step_m * 0.99 if max_step is None else min(max_step, lim.max_step_m * 0.99)
        step = float(np.linalg.norm(dX))
        run.gap_m = step
        if step > cap:
            dX = dX * (cap / step)
        angle = float(np.linalg.norm(rv))
        run.gap_rad = angle
        if angle > lim.max_step_rad * 0.99:
            rv = rv * (lim.max_step_rad * 0.99 / angle)
        # Scale 1 would be applied by the DecisionServer to every client's increments:
        # the task's increments are absolute distances, so undo the operator's scale.
        scale = decision.scale
        try:
            if run.named:
                await decision.cartesian_increment(
                    task.client_id, dX / scale, rv / scale, frame=WorkingFrame.BASE, arm=run.name
                )
            else:
                await decision.cartesian_increment(
                    task.client_id, dX / scale, rv / scale, frame=WorkingFrame.BASE
                )
        except TelerobotError as exc:
            raise self._refused(run, exc) from exc
