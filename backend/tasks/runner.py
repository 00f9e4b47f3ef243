"""The TaskRunner: repeats a taught motion (a ``Trajectory``) with the server's own
loop, through the DecisionServer, while the operator supervises.

**The lease.** A task is a client of the DecisionServer like any other (its own
client, named "task N"): only the operator *holding the control lease* can start
one, and starting it hands the lease to the task. So the task moves under exactly
the rules of every command (role, lease, e-stop, step and speed limits, contact
slowing, the force limit's back-away-only rule, workspace, IK, joint steps), and the
DecisionServer's own dead-man watches the *task's* loop: the loop heartbeats by
commanding every period (also while paused: it holds the path point), so a stalled
loop is stopped by the dead-man like a silent operator. The operator takes control
back at any time by taking the lease (the task stops: lease loss), and when the task
ends the lease is handed back to the operator who started it. Running the task under
the operator's own lease instead would mix two loops' heartbeats in one client, so a
dead page could not be told from a live task. The operator stays present by its own
connection (a page) or its heartbeats (a script: ``POST /lease/heartbeat`` is taken
from the supervisor of the task holding the lease), whether or not it holds the lease.

**Guards**, checked every period before moving: the e-stop, lease loss, the force
limit (the DecisionServer's), the supervising operator gone (its connection closed),
and a contact force stronger than the one recorded at that point by more than
``force_margin_n`` (an obstacle the recording did not have). A task starts only within
``start_tolerance_m`` of its first pose, or with ``approach`` (the operator's
confirmation), after a slow guarded move there: a move in joints along the line to the
first pose's joints, checked before it starts (``approach.py``).

**Compliance**: the admittance offset (``compliance.py``) is added to each commanded
position along the chosen axes.

**Keeping to the path, and saying so.** The path's clock waits for the arm: while the
commanded target is more than ``hold_gap_m`` from the path's point (the path moves
faster than the speed limit lets the arm, or the contact slowing holds it back), the
task's time does not advance, so no stretch of the path is cut short; an arm that
gets no closer for ``stall_s`` stops the task, saying where. A recording whose path
*jumps* (a stretch the arm cannot follow at the taught pace: it would fall more than
``JUMP_LAG_M`` behind, e.g. a pose 1 m from the one before it) starts only with
``allow_jumps`` (the operator's confirmation: the arm crosses it in a straight line at
the speed limit). A task ends ``done`` only with the tool within ``end_tolerance_m``
of the path's end; otherwise ``stopped``, with how far from it the tool came to rest.

**Two arms or more** (docs/tasks.md): a task from a multi-arm recording repeats every
recorded arm's path together, each on this server's arm of the same name (the reader
refuses a recording whose arms are not this server's). One path clock drives them all:
it waits while any arm is behind, and the task is done when every arm is at its path's
end. Each arm has its own guards: its force limit (the DecisionServer's), its margin over
the force recorded on that arm, its compliance, its approach; a contact on one arm stops
the task and the reason names the arm. The task's commands name their arm (``arm=``);
a one-arm task's name none, as before.

Time is the injected clock's; the loop runs every ``period_s``. Here: starting,
pausing and ending tasks, the lease handed to and fro, and the loop; one period of
it (the guards, the path's clock, each arm's command) is ``period.py``, the task's
data ``task.py``.
"""

from __future__ import annotations

import asyncio
import builtins
import contextlib
import itertools
import logging
import math
from collections import OrderedDict

from telerobot.drivers.base import (
    FloatArray,
    InvalidCommand,
    RobotStatus,
    TelerobotError,
)
from telerobot.drivers.clock import Clock
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.clients import Role
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed, SafetyStop
from telerobot.server.tasks.approach import ApproachPlan, plan_approach
from telerobot.server.tasks.compliance import Admittance
from telerobot.server.tasks.period import TaskPeriod, distance_to, distance_to_start
from telerobot.server.tasks.source_reader import SourceReader
from telerobot.server.tasks.task import START_TOLERANCE_M as START_TOLERANCE_M
from telerobot.server.tasks.task import START_TOLERANCE_RAD as START_TOLERANCE_RAD
from telerobot.server.tasks.task import ArmRun as ArmRun
from telerobot.server.tasks.task import AwayFromStart as AwayFromStart
from telerobot.server.tasks.task import PathJumps as PathJumps
from telerobot.server.tasks.task import Task as Task
from telerobot.server.tasks.task import TaskBusy as TaskBusy
from telerobot.server.tasks.task import TaskEvents as TaskEvents
from telerobot.server.tasks.task import TaskSpec as TaskSpec
from telerobot.server.tasks.task import TaskState as TaskState
from telerobot.server.tasks.task import UnknownTask as UnknownTask
from telerobot.server.tasks.trajectory import Trajectory

log = logging.getLogger(__name__)

MAX_FINISHED = 32  # finished tasks kept for GET; the oldest goes first
# A path the arm would fall this far behind at the speed limits jumps: it needs the
# operator's confirmation (allow_jumps). Jitter in a taught path's time stamps adds
# millimetres; a jump is a pose far from the one before it.
JUMP_LAG_M = 0.02
JUMP_LAG_RAD = math.radians(10.0)


class TaskRunner:
    """Runs one task at a time; keeps the last ``MAX_FINISHED`` finished ones."""

    def __init__(
        self,
        decision: DecisionServer,
        clock: Clock,
        *,
        operator_token: str,
        period_s: float = 0.02,
        settle_s: float = 1.0,
    ) -> None:
        self.decision = decision
        self.clock = clock
        self.period_s = period_s
        self.settle_s = settle_s  # after the path's end, how long the arm may take to arrive
        self.events = TaskEvents()
        self._token = operator_token
        self._tasks: OrderedDict[str, Task] = OrderedDict()
        self._ids = itertools.count(1)
        # Reads the recordings tasks and their previews come from (off the loop, one
        # at a time, budgeted per address; this server's arms' only).
        self.sources = SourceReader(
            clock=clock.now,
            arm_models={guard.name: guard.robot.model.name for guard in decision.arms},
        )
        self._period = TaskPeriod(decision, clock, self._changed)

    # ------------------------------------------------------------ queries
    def get(self, task_id: str) -> Task:
        try:
            return self._tasks[task_id]
        except KeyError:
            raise UnknownTask(f"there is no task {task_id!r}") from None

    def list(self) -> list[Task]:
        return list(self._tasks.values())

    @property
    def active(self) -> Task | None:
        return next((t for t in self._tasks.values() if not t.state.finished), None)

    def distance_to_start(self, trajectory: Trajectory, guard: ArmGuard) -> tuple[float, float]:
        """How far ``guard``'s arm's tool is from the trajectory's first pose (m, rad)."""
        return distance_to_start(trajectory, guard)

    def distance_to(
        self, position: FloatArray, rotation: FloatArray, guard: ArmGuard
    ) -> tuple[float, float]:
        """How far ``guard``'s arm's tool is from the pose (m, rad)."""
        return distance_to(position, rotation, guard)

    async def plan_approach(
        self,
        position: FloatArray,
        rotation: FloatArray,
        *,
        guard: ArmGuard,
        tolerance_m: float = START_TOLERANCE_M,
        tolerance_rad: float = START_TOLERANCE_RAD,
    ) -> ApproachPlan:
        """The joint move from ``guard``'s arm's commanded joints to the tool pose (a
        task's first pose), checked (``approach.plan_approach``); InvalidCommand if none."""
        return await guard.off_loop(  # the full IK: off the event loop
            plan_approach,
            guard.limits,
            guard.robot.target_joints,
            position,
            rotation,
            # The approach hands over to the path at half the start's tolerance: its goal
            # must be well within that (a 5-joint arm meets an orientation nearly).
            tolerance_m=tolerance_m / 4,
            tolerance_rad=tolerance_rad / 4,
        )

    # ------------------------------------------------------------ control
    def _runs(self, spec: TaskSpec) -> builtins.list[ArmRun]:
        """Each arm's part of ``spec``: the only arm's, or each named arm's (each with its
        own force sensor)."""
        decision = self.decision
        if not spec.arm_paths:
            only = decision.arm(None)
            return [ArmRun(only, spec.trajectory, only.force, named=False)]
        named = len(decision.arms) > 1
        runs = []
        for name, trajectory in spec.arm_paths:
            guard = decision.arm(name)
            runs.append(ArmRun(guard, trajectory, guard.force, named=named))
        return runs

    async def start(self, spec: TaskSpec, supervisor_id: str) -> Task:
        """Start ``spec`` for the operator ``supervisor_id``, who must hold the lease:
        the task takes it over for its run and hands it back at the end."""
        decision = self.decision
        supervisor = decision.clients.get(supervisor_id)
        if supervisor.role is not Role.OPERATOR:
            raise NotAllowed("observers cannot start tasks: connect with the operator token")
        if decision.lease_holder != supervisor_id:
            raise NotAllowed(
                "take the control lease first: a task runs on the lease its operator hands it"
            )
        state = decision.state()
        if state.estop:
            raise SafetyStop(f"e-stop is latched ({state.estop_reason}): reset it first")
        if state.force_limited:
            where = "" if len(decision.arms) == 1 else f" on {_arms(state.force_limited_arms)}"
            raise SafetyStop(f"the force limit is active{where}: back away from the contact first")
        if self.active is not None:
            raise TaskBusy(f"task {self.active.id} is running: abort it first")
        runs = self._runs(spec)
        for run in runs:
            self._check_jumps(spec, run)
        for run in runs:
            run.start_offset = self.distance_to_start(run.trajectory, run.guard)
        away = [run for run in runs if not self._near(spec, run)]
        if away and not spec.approach:
            distance, angle = away[0].start_offset
            raise AwayFromStart(
                away[0].said(
                    f"the tool is {distance * 1000:.1f} mm / {math.degrees(angle):.1f}° from "
                    f"the task's first pose (it starts within "
                    f"{spec.start_tolerance_m * 1000:.0f} mm / "
                    f"{math.degrees(spec.start_tolerance_rad):.0f}°): move there, or confirm the "
                    "approach (approach: true), a slow joint move there (its way: POST "
                    "/tasks/preview, approach)"
                )
            )
        for run in away:  # checked before the lease changes hands: a refusal moves nothing
            p0, R0, _ = run.trajectory.at(0.0)
            try:
                run.approach = await self.plan_approach(
                    p0,
                    R0,
                    tolerance_m=spec.start_tolerance_m,
                    tolerance_rad=spec.start_tolerance_rad,
                    guard=run.guard,
                )
            except InvalidCommand as exc:
                if not run.named:
                    raise
                raise InvalidCommand(run.said(str(exc))) from None
        for run in runs:
            run.approached = run.approach is None
            run.admittance = Admittance(spec.compliance) if spec.compliance else None
        task_id = str(next(self._ids))
        # Run for its supervisor: its heartbeats keep it present while the task holds
        # the lease (a script's keep-alive goes on; DecisionServer.heartbeat).
        client = decision.join(
            f"task {task_id}", self._token, source="task", on_behalf_of=supervisor_id
        )
        try:
            await decision.take_lease(client.id, force=True)
        except TelerobotError:
            await decision.leave(client.id)
            raise
        task = Task(
            id=task_id,
            spec=spec,
            supervisor_id=supervisor_id,
            supervisor_name=supervisor.name,
            client_id=client.id,
            state=TaskState.APPROACHING if away else TaskState.RUNNING,
            runs=runs,
        )
        self._remember(task)
        log.info("task %s starts (%s) for %s", task_id, spec.trajectory.source, supervisor.name)
        task.loop = asyncio.get_running_loop().create_task(self._run(task), name=f"task-{task_id}")
        self._changed(task)
        return task

    @staticmethod
    def _near(spec: TaskSpec, run: ArmRun) -> bool:
        distance, angle = run.start_offset
        return distance <= spec.start_tolerance_m and angle <= spec.start_tolerance_rad

    def _check_jumps(self, spec: TaskSpec, run: ArmRun) -> None:
        lim = run.guard.limits
        lag_m, lag_rad, at = run.trajectory.lag_behind(
            lim.max_speed_m_s, lim.max_angular_speed_rad_s, spec.speed
        )
        if (lag_m > JUMP_LAG_M or lag_rad > JUMP_LAG_RAD) and not spec.allow_jumps:
            raise PathJumps(
                run.said(
                    f"the recorded path jumps near s = {at:.2f} s: at {spec.speed:g}× the taught "
                    f"pace it moves faster than the arm may ({lim.max_speed_m_s:g} m/s, "
                    f"{math.degrees(lim.max_angular_speed_rad_s):.0f}°/s), so the tool would fall "
                    f"{lag_m * 1000:.0f} mm / {math.degrees(lag_rad):.0f}° behind and cross "
                    "that stretch in a straight line at the speed limit: confirm with "
                    "allow_jumps: true, or choose a segment without it"
                )
            )

    def _remember(self, task: Task) -> None:
        self._tasks[task.id] = task
        while len(self._tasks) > MAX_FINISHED + 1:
            oldest = next(iter(self._tasks.values()))
            if not oldest.state.finished:
                break
            self._tasks.popitem(last=False)

    def _check_supervisor(self, task: Task, client_id: str) -> None:
        client = self.decision.clients.get(client_id)
        if client.role is not Role.OPERATOR:
            raise NotAllowed("observers cannot change a task: connect with the operator token")

    def pause(self, task_id: str, client_id: str) -> Task:
        task = self.get(task_id)
        self._check_supervisor(task, client_id)
        if task.state is TaskState.RUNNING:
            task.state = TaskState.PAUSED
            self._changed(task)
        elif task.state is not TaskState.PAUSED:
            raise InvalidCommand(f"task {task_id} is {task.state}: only a running task pauses")
        return task

    def resume(self, task_id: str, client_id: str) -> Task:
        task = self.get(task_id)
        self._check_supervisor(task, client_id)
        if task.state is TaskState.PAUSED:
            task.state = TaskState.RUNNING
            self._changed(task)
        elif task.state is not TaskState.RUNNING:
            raise InvalidCommand(f"task {task_id} is {task.state}: only a paused task resumes")
        return task

    async def abort(self, task_id: str, client_id: str) -> Task:
        task = self.get(task_id)
        self._check_supervisor(task, client_id)
        if not task.state.finished:
            await self._end(task, TaskState.ABORTED, "aborted by the operator")
        return task

    async def stop(self) -> None:
        """Server shutdown: end every task."""
        self.sources.close()
        for task in list(self._tasks.values()):
            if not task.state.finished:
                await self._end(task, TaskState.ABORTED, "the server is stopping")

    # ------------------------------------------------------------ the loop
    async def _run(self, task: Task) -> None:
        last = self.clock.now()
        settle_until: float | None = None
        try:
            while not task.state.finished:
                await self.clock.sleep(self.period_s)
                if task.state.finished:
                    return
                now = self.clock.now()
                dt, last = now - last, now
                why = self._period.guard(task)
                if why is not None:
                    await self._end(task, TaskState.STOPPED, why)
                    return
                if await self._period.step(task, dt):
                    settle_until = settle_until if settle_until is not None else now + self.settle_s
                    arrived = all(
                        run.guard.robot.status is not RobotStatus.MOVING for run in task.runs
                    )
                    if arrived or now >= settle_until:
                        short = self._period.short_of_end(task, arrived, self.settle_s)
                        state = TaskState.DONE if not short else TaskState.STOPPED
                        await self._end(task, state, short)
                        return
        except TelerobotError as exc:
            await self._end(task, TaskState.STOPPED, str(exc))
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # a bug must not leave the lease with a dead task
            log.exception("task %s failed", task.id)
            await self._end(task, TaskState.STOPPED, f"internal error: {exc}")

    async def _end(self, task: Task, state: TaskState, reason: str) -> None:
        if task.state.finished:
            return
        task.state, task.reason = state, reason
        log.info("task %s %s%s", task.id, state, f": {reason}" if reason else "")
        decision = self.decision
        if decision.lease_holder == task.client_id:
            for run in task.runs:
                await run.guard.robot.stop()
            # Hand the lease back to the operator who started the task, if still here.
            try:
                decision.clients.get(task.supervisor_id)
                await decision.take_lease(task.supervisor_id, force=True)
            except TelerobotError:
                await decision.release_lease(task.client_id)
        await decision.leave(task.client_id)
        task.finished.set()
        self._changed(task)
        current = asyncio.current_task()
        if task.loop is not None and task.loop is not current:
            task.loop.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task.loop

    def _changed(self, task: Task) -> None:
        self.events.changed.emit(task.status())


def _arms(names: tuple[str, ...]) -> str:
    return ", ".join(names) if names else "an arm"
