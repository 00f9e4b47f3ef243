"""A task as the TaskRunner (runner.py) keeps it: what was asked (``TaskSpec``), each
arm's part (``ArmRun``), where it is (``Task``, ``TaskState``, its trace) and what is
said of it (``TaskStatus``, the refusals). Data and its own checks only: the loop is
runner.py's, one period of it period.py's."""

from __future__ import annotations

import asyncio
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

import numpy as np

from telerobot.drivers.base import FloatArray, ForceSensor, InvalidCommand, TelerobotError
from telerobot.drivers.events import Event
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.recording.schemas import SINGLE_ARM
from telerobot.server.tasks.approach import ApproachPlan
from telerobot.server.tasks.compliance import Admittance, ComplianceSettings
from telerobot.server.tasks.trajectory import Trajectory

TRACE_LIMIT = 60_000  # periods traced per task (20 min at 50 Hz)
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
