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

Time is the injected clock's; the loop runs every ``period_s``.
"""

from __future__ import annotations

import asyncio
import builtins
import contextlib
import itertools
import logging
import math
from collections import OrderedDict, deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import (
    FloatArray,
    ForceSensor,
    InvalidCommand,
    RobotStatus,
    TelerobotError,
    WorkingFrame,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.clients import Role
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed, SafetyStop
from telerobot.server.recording.schemas import SINGLE_ARM
from telerobot.server.tasks.approach import ApproachPlan, approach_step, plan_approach
from telerobot.server.tasks.compliance import Admittance, ComplianceSettings
from telerobot.server.tasks.source_reader import SourceReader
from telerobot.server.tasks.trajectory import Trajectory

log = logging.getLogger(__name__)

MAX_FINISHED = 32  # finished tasks kept for GET; the oldest goes first
TRACE_LIMIT = 60_000  # periods traced per task (20 min at 50 Hz)
# A path the arm would fall this far behind at the speed limits jumps: it needs the
# operator's confirmation (allow_jumps). Jitter in a taught path's time stamps adds
# millimetres; a jump is a pose far from the one before it.
JUMP_LAG_M = 0.02
JUMP_LAG_RAD = math.radians(10.0)
# A task starts within this of its first pose (else it needs an approach).
START_TOLERANCE_M = 0.005
START_TOLERANCE_RAD = math.radians(3.0)


class TaskBusy(TelerobotError):
    """Another task is running: abort it first."""

    code = "task_busy"
    http_status = 409


class PathJumps(InvalidCommand):
    """The recorded path has a stretch the arm cannot follow at the taught pace."""

    code = "path_jumps"


class AwayFromStart(InvalidCommand):
    """The tool is away from the task's first pose and no approach was confirmed."""

    code = "away_from_start"


class UnknownTask(TelerobotError):
    code = "not_found"
    http_status = 404


class ArmRefused(TelerobotError):
    """A multi-arm task's command for one arm was refused (the reason names the arm)."""

    code = "arm_refused"


class TaskState(StrEnum):
    APPROACHING = "approaching"  # the guarded move to the first pose
    RUNNING = "running"
    PAUSED = "paused"
    DONE = "done"
    STOPPED = "stopped"  # a guard or a refused command ended it
    ABORTED = "aborted"  # the operator ended it

    @property
    def finished(self) -> bool:
        return self in (TaskState.DONE, TaskState.STOPPED, TaskState.ABORTED)


@dataclass(frozen=True)
class TaskSpec:
    trajectory: Trajectory  # the one arm's path (of several arms: the first's)
    speed: float = 1.0  # share of the taught speed, 0.1–1
    compliance: ComplianceSettings | None = None
    force_margin_n: float | None = 15.0  # None: no unexpected-contact guard
    approach: bool = False  # the operator confirms a guarded move to the first pose
    allow_jumps: bool = False  # the operator confirms the path's jumps, crossed at the limit
    start_tolerance_m: float = START_TOLERANCE_M
    start_tolerance_rad: float = START_TOLERANCE_RAD
    # The approach's pace: the tool's speed, and the joints' (each within the arm's).
    approach_speed_m_s: float = 0.02
    approach_joint_speed_rad_s: float = 0.2
    # At the end, the tool within this of the path's last pose: done (else stopped).
    end_tolerance_m: float = 0.005
    end_tolerance_rad: float = math.radians(3.0)
    # The path's clock waits while the commanded target is further than this behind;
    # a wait with no millimetre gained for stall_s stops the task.
    hold_gap_m: float = 0.01
    hold_gap_rad: float = math.radians(3.0)
    stall_s: float = 2.0
    # The margin compares with the strongest force recorded this near in time.
    margin_window_s: float = 0.25
    # Several arms (a multi-arm recording's): each arm's name and path, the first's being
    # ``trajectory``. Empty: one arm's task, on the server's only arm.
    arm_paths: tuple[tuple[str, Trajectory], ...] = ()

    def __post_init__(self) -> None:
        if not (isinstance(self.speed, int | float) and 0.1 <= self.speed <= 1.0):
            raise InvalidCommand(f"speed is a share of the taught speed, 0.1–1, got {self.speed}")
        m = self.force_margin_n
        if m is not None and not (math.isfinite(m) and 0.5 <= m <= 200.0):
            raise InvalidCommand(f"force_margin_n must be 0.5–200 N, got {m}")
        if any(len(traj) < 2 for _, traj in self.paths):
            raise InvalidCommand("a task needs a trajectory of at least two poses")
        names = [name for name, _ in self.arm_paths]
        if len(set(names)) != len(names):
            raise InvalidCommand(f"a task moves each arm once, not {names}")

    @classmethod
    def of_paths(cls, paths: Mapping[str, Trajectory], **options: Any) -> TaskSpec:
        """The task repeating each recorded arm's path (``read_paths``): one arm's
        ("arm", a one-arm recording's) on the only arm, several on the arms they name."""
        items = list(paths.items())
        if not items:
            raise InvalidCommand("a task needs a trajectory of at least two poses")
        if len(items) == 1 and items[0][0] == SINGLE_ARM:
            return cls(items[0][1], **options)
        return cls(items[0][1], arm_paths=tuple(items), **options)

    @property
    def paths(self) -> list[tuple[str | None, Trajectory]]:
        """Each arm's name (None: the only arm) and path."""
        if not self.arm_paths:
            return [(None, self.trajectory)]
        return [(name, traj) for name, traj in self.arm_paths]

    @property
    def duration(self) -> float:
        return max(traj.duration for _, traj in self.paths)


@dataclass(frozen=True)
class TracePoint:
    t: float  # server clock
    s: float  # trajectory time
    force_n: float  # measured contact force magnitude (of several arms: the strongest)
    recorded_n: float  # recorded at this point of the path (on that arm)
    offset: tuple[float, float, float]  # compliance offset, base frame, m (the first arm's)


@dataclass(frozen=True)
class TaskStatus:
    id: str
    state: TaskState
    reason: str
    progress: float  # 0–1 of the trajectory's duration
    s: float  # trajectory time reached, s
    duration: float  # trajectory duration at the taught speed, s
    speed: float
    force_n: float  # the last measured contact force (of several arms: the strongest)
    recorded_n: float  # and the recorded one at that point (on that arm)
    peak_force_n: float
    offset: tuple[float, float, float]
    supervisor: str  # the operator who started it (client name)
    source: str  # the trajectory's origin
    arms: tuple[str, ...] = ()  # the arms it moves, of a multi-arm task (else none)


@dataclass(eq=False)
class ArmRun:
    """One arm's part of a task: its path and guard (driver, model, limits), its force
    sensor, compliance and approach, how far its commanded target is behind the path,
    and the forces it feels and was taught."""

    guard: ArmGuard
    trajectory: Trajectory
    force: ForceSensor | None
    named: bool  # its commands name it (a multi-arm server's); else the only arm
    admittance: Admittance | None = None
    approach: ApproachPlan | None = None  # the joint move to the first pose, if it needs one
    approached: bool = False  # …and it is there
    start_offset: tuple[float, float] = (0.0, 0.0)  # the tool from the first pose at start
    gap_m: float = 0.0  # how far the commanded target was from the path's point
    gap_rad: float = 0.0
    held_gap: float = math.inf  # the approach: the smallest joint gap so far…
    held_since: float | None = None  # …and when it last shrank
    force_n: float = 0.0
    recorded_n: float = 0.0
    measured: FloatArray = field(default_factory=lambda: np.zeros(3))  # base frame, N

    @property
    def name(self) -> str:
        return self.guard.name

    def said(self, text: str) -> str:
        """``text`` about this arm, named when the task moves arms by name."""
        return f"{self.name}: {text}" if self.named else text


@dataclass
class Task:
    id: str
    spec: TaskSpec
    supervisor_id: str
    supervisor_name: str
    client_id: str
    state: TaskState
    runs: list[ArmRun]  # each arm's part, in the task's arm order
    reason: str = ""
    s: float = 0.0
    force_n: float = 0.0
    recorded_n: float = 0.0
    peak_force_n: float = 0.0
    held_gap: float = math.inf  # the smallest gap while the path's clock waits…
    held_since: float | None = None  # …and when it last shrank by a millimetre
    trace: deque[TracePoint] = field(default_factory=lambda: deque(maxlen=TRACE_LIMIT))
    loop: asyncio.Task[None] | None = None
    finished: asyncio.Event = field(default_factory=asyncio.Event)

    @property
    def admittance(self) -> Admittance | None:
        """The first arm's compliance."""
        return self.runs[0].admittance

    @property
    def approach(self) -> ApproachPlan | None:
        """The first arm's approach."""
        return self.runs[0].approach

    @property
    def start_offset(self) -> tuple[float, float]:
        """The first arm's tool from its first pose at start (m, rad)."""
        return self.runs[0].start_offset

    @property
    def gap_m(self) -> float:
        """How far the commanded target furthest behind was from the path's point."""
        return max(run.gap_m for run in self.runs)

    @property
    def gap_rad(self) -> float:
        return max(run.gap_rad for run in self.runs)

    def status(self) -> TaskStatus:
        spec = self.spec
        duration = spec.duration
        offset = self.admittance.offset if self.admittance else np.zeros(3)
        return TaskStatus(
            id=self.id,
            state=self.state,
            reason=self.reason,
            progress=min(self.s / duration, 1.0) if duration > 0 else 1.0,
            s=self.s,
            duration=duration,
            speed=spec.speed,
            force_n=self.force_n,
            recorded_n=self.recorded_n,
            peak_force_n=self.peak_force_n,
            offset=(float(offset[0]), float(offset[1]), float(offset[2])),
            supervisor=self.supervisor_name,
            source=spec.trajectory.source,
            arms=tuple(run.name for run in self.runs if run.named),
        )


@dataclass
class TaskEvents:
    changed: Event[TaskStatus] = field(default_factory=lambda: Event("task_changed"))


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
        p0, R0, _ = trajectory.at(0.0)
        return self.distance_to(p0, R0, guard)

    def distance_to(
        self, position: FloatArray, rotation: FloatArray, guard: ArmGuard
    ) -> tuple[float, float]:
        """How far ``guard``'s arm's tool is from the pose (m, rad)."""
        pose = guard.robot.pose
        angle = float(np.linalg.norm(pin.log3(pose.rotation.T @ rotation)))
        return float(np.linalg.norm(pose.position - position)), angle

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
                why = self._guard(task)
                if why is not None:
                    await self._end(task, TaskState.STOPPED, why)
                    return
                if await self._step(task, dt):
                    settle_until = settle_until if settle_until is not None else now + self.settle_s
                    arrived = all(
                        run.guard.robot.status is not RobotStatus.MOVING for run in task.runs
                    )
                    if arrived or now >= settle_until:
                        short = self._short_of_end(task, arrived)
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

    def _guard(self, task: Task) -> str | None:
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

    def _short_of_end(self, task: Task, arrived: bool) -> str:
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
                else f"was still {where} {self.settle_s:g} s after it was sent there"
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

    async def _step(self, task: Task, dt: float) -> bool:
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
            self._changed(task)

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
        distance, angle = self.distance_to_start(run.trajectory, guard)
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
