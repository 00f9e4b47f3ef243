"""Supervisory tasks (docs/tasks.md): repeat a recorded episode, or a time segment of a
recording, as a server-side task under the DecisionServer's guards. Starting one
needs the operator token and the control lease (``X-Client-Id``): the lease goes to
the task for its run and comes back at its end. Reading is open to every client;
a preview reads a recording, so without the operator token it is budgeted per
address and one at a time (429 past it; backend/tasks/source_reader.py). The
recording being written is refused (409); a torn one is read as far as it is valid."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Depends, Request
from pydantic import BaseModel, Field

from telerobot.drivers.base import InvalidCommand
from telerobot.server.api.deps import ClientDep, DecisionDep, ServicesDep
from telerobot.server.api.requests import StrictRequest
from telerobot.server.recording.recorder import Recorder, RecordingError
from telerobot.server.security import bearer
from telerobot.server.tasks.approach import ApproachPlan
from telerobot.server.tasks.compliance import ComplianceSettings
from telerobot.server.tasks.runner import (
    START_TOLERANCE_M,
    START_TOLERANCE_RAD,
    Task,
    TaskRunner,
    TaskSpec,
)
from telerobot.server.tasks.source_reader import PathPreview
from telerobot.server.tasks.trajectory import OtherArms, Trajectory

MAX_FILE_NAME = 255  # a file name's bytes on every common file system (ASCII names here)

router = APIRouter(prefix="/tasks", tags=["tasks"])


def _runner(s: ServicesDep) -> TaskRunner:
    return s.task_runner


def _recorder(s: ServicesDep) -> Recorder:
    return s.recorder


RunnerDep = Annotated[TaskRunner, Depends(_runner)]
RecorderDep = Annotated[Recorder, Depends(_recorder)]


class Compliance(StrictRequest):
    axes: str = Field("xyz", pattern=r"^[xyz]{0,3}$", description="base axes that give way")
    stiffness_n_per_m: float = Field(1000.0, ge=10, le=1e6)
    damping_n_s_per_m: float = Field(2000.0, ge=1, le=1e6)
    max_offset_m: float = Field(0.01, ge=0, le=0.05)
    max_rate_m_s: float = Field(0.02, ge=0, le=0.1)


class TaskSource(StrictRequest):
    recording: str = Field(
        max_length=MAX_FILE_NAME, description="a recording's file name (GET /api/v1/recordings)"
    )
    episode: int | None = Field(None, ge=0, description="repeat this episode")
    segment: tuple[float, float] | None = Field(
        None, description="or this span [t0, t1] s (of the episode, else of the recording)"
    )
    arm: str | None = Field(
        None,
        max_length=64,
        description="on a server of several arms, the arm to repeat a one-arm recording on"
        " (a recording of several arms repeats each on the arm of its name: leave it out)",
    )


class StartTask(TaskSource):
    speed: float = Field(1.0, ge=0.1, le=1.0, description="share of the taught speed")
    compliance: Compliance | None = Field(None, description="none: position only")
    force_margin_n: float | None = Field(
        15.0, ge=0.5, le=200, description="stop on a force this much above the taught one"
    )
    approach: bool = Field(
        False,
        description="the operator confirms the approach: a slow joint move to the first pose "
        "first (its way: POST /tasks/preview, approach)",
    )
    allow_jumps: bool | None = Field(
        None,
        description="the operator confirms that the path's jumps (stretches faster than the "
        "arm may move) are crossed in a straight line at the speed limit (null: no)",
    )


class TaskView(BaseModel):
    id: str
    state: Literal["approaching", "running", "paused", "done", "stopped", "aborted"]
    reason: str
    progress: float
    s: float
    duration: float
    speed: float
    force_n: float
    recorded_n: float
    peak_force_n: float
    offset: tuple[float, float, float]
    supervisor: str
    source: str


class TaskPath(BaseModel):
    id: str
    positions: list[tuple[float, float, float]]  # base frame, metres, at most 400
    forces_n: list[float]  # the recorded force's magnitude at each
    start_distance_m: float = Field(
        description="how far the tool is from the first pose (a task's: when it started)"
    )
    start_angle_rad: float
    approach: list[tuple[float, float, float]] = Field(
        description="the tool's way from where it is to the first pose, base frame, metres, "
        "at most 100: the approach, a joint move (empty: it starts there, or it cannot go)"
    )
    approach_refused: str = Field(
        description="why the tool cannot approach the first pose from where it is ('' if it can)"
    )


def _points(a: np.ndarray) -> list[tuple[float, float, float]]:
    return [(float(x), float(y), float(z)) for x, y, z in a.tolist()]


def _path(
    task_id: str,
    preview: PathPreview,
    start: tuple[float, float],
    approach: ApproachPlan | None,
    refused: str = "",
) -> TaskPath:
    return TaskPath(
        id=task_id,
        positions=_points(preview.positions),
        forces_n=preview.forces_n.tolist(),
        start_distance_m=start[0],
        start_angle_rad=start[1],
        approach=[] if approach is None else _points(approach.positions),
        approach_refused=refused,
    )


def _source(body: TaskSource, recorder: Recorder) -> Path:
    """The recording's path; the one being written is refused (it has no end yet)."""
    if body.segment is not None and not body.segment[0] < body.segment[1]:
        raise InvalidCommand("a segment is [t0, t1] with t0 < t1")
    path = recorder.path_of(body.recording)
    active = recorder.status()
    if active is not None and active["file"] == path.name:
        raise RecordingError(
            f"{path.name} is being recorded: stop it first, then preview or repeat it"
        )
    return path


def _caller(request: Request, decision: DecisionDep) -> tuple[bool, str]:
    """Whether the request carries the operator token, and its address (the budget's)."""
    token = bearer(request.headers.get("authorization"))
    address = request.client.host if request.client is not None else "unknown"
    return decision.clients.check_token(token), address


async def _paths(body: TaskSource, recorder: Recorder, runner: TaskRunner) -> dict[str, Trajectory]:
    """Each recorded arm's path (one arm's, or a multi-arm recording's each; a one-arm
    recording's on ``body.arm`` when named)."""
    path = _source(body, recorder)
    with _one_arm_only(body, path):
        return await runner.sources.paths(
            path, body.episode, body.segment, operator=True, address="", onto=body.arm
        )


@contextlib.contextmanager
def _one_arm_only(body: TaskSource, path: Path) -> Iterator[None]:
    """``arm`` names where a one-arm recording goes: a recording of several arms,
    read with it, is refused saying so (not as the arms it did not find)."""
    try:
        yield
    except OtherArms:
        if body.arm is None:
            raise
        raise OtherArms(
            f"{path.name} was recorded with several arms, each repeated on this server's"
            " arm of its name: leave arm out (it names the arm for a one-arm recording)"
        ) from None


def _view(task: Task) -> TaskView:
    st = task.status()
    return TaskView(
        id=st.id,
        state=st.state.value,
        reason=st.reason,
        progress=st.progress,
        s=st.s,
        duration=st.duration,
        speed=st.speed,
        force_n=st.force_n,
        recorded_n=st.recorded_n,
        peak_force_n=st.peak_force_n,
        offset=st.offset,
        supervisor=st.supervisor,
        source=st.source,
    )


@router.get("")
async def list_tasks(runner: RunnerDep) -> list[TaskView]:
    return [_view(t) for t in runner.list()]


@router.post("")
async def start_task(
    body: StartTask, runner: RunnerDep, recorder: RecorderDep, client: ClientDep
) -> TaskView:
    """Read the recording, build the trajectory and start it (it runs on its own;
    poll GET /tasks/{id})."""
    paths = await _paths(body, recorder, runner)
    c = body.compliance
    spec = TaskSpec.of_paths(
        paths,
        speed=body.speed,
        compliance=None if c is None else ComplianceSettings(**c.model_dump()),
        force_margin_n=body.force_margin_n,
        approach=body.approach,
        allow_jumps=bool(body.allow_jumps),
    )
    return _view(await runner.start(spec, client.id))


@router.post("/preview")
async def preview_task(
    body: TaskSource,
    request: Request,
    runner: RunnerDep,
    recorder: RecorderDep,
    decision: DecisionDep,
) -> TaskPath:
    """The path a task from this episode or segment would follow, before it runs (the
    same trajectory POST /tasks builds), for the page's ghost of it. Moves nothing.
    Without the operator token: a budget per address and one read at a time (429)."""
    operator, address = _caller(request, decision)
    path = _source(body, recorder)
    with _one_arm_only(body, path):
        preview = await runner.sources.preview(
            path, body.episode, body.segment, operator=operator, address=address, onto=body.arm
        )
    # The approach from where the arm is now, as POST /tasks would plan it (of a
    # multi-arm recording: its first arm's, on this server's arm of that name).
    p0, R0 = preview.positions[0], preview.start_rotation
    guard = decision.arm(None if len(decision.arms) == 1 else preview.arm)
    distance, angle = runner.distance_to(p0, R0, guard)
    plan, refused = None, ""
    if distance > START_TOLERANCE_M or angle > START_TOLERANCE_RAD:
        try:
            plan = await runner.plan_approach(p0, R0, guard=guard)
        except InvalidCommand as exc:
            refused = str(exc)
    return _path("preview", preview, (distance, angle), plan, refused)


@router.get("/{task_id}")
async def get_task(task_id: str, runner: RunnerDep) -> TaskView:
    return _view(runner.get(task_id))


@router.get("/{task_id}/path")
async def task_path(task_id: str, runner: RunnerDep) -> TaskPath:
    """The path the task follows, for the page's ghost of it."""
    task = runner.get(task_id)
    first = task.runs[0]  # (of a multi-arm task: its first arm's)
    return _path(task.id, PathPreview.of(first.trajectory), first.start_offset, first.approach)


@router.post("/{task_id}/pause")
async def pause_task(task_id: str, runner: RunnerDep, client: ClientDep) -> TaskView:
    return _view(runner.pause(task_id, client.id))


@router.post("/{task_id}/resume")
async def resume_task(task_id: str, runner: RunnerDep, client: ClientDep) -> TaskView:
    return _view(runner.resume(task_id, client.id))


@router.post("/{task_id}/abort")
async def abort_task(task_id: str, runner: RunnerDep, client: ClientDep) -> TaskView:
    return _view(await runner.abort(task_id, client.id))
