"""The control lease, safety (e-stop, limits) and motion settings (scale, frame)."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Annotated

import numpy as np
from fastapi import APIRouter, Header, Query, Request
from pydantic import BaseModel, Field, field_validator

from telerobot.drivers.base import StopCategory, WorkingFrame
from telerobot.protocol.names import MAX_NAME, RULE, name_problem
from telerobot.server.api.deps import (
    ClientDep,
    DecisionDep,
    DriverClientDep,
    DriverDep,
    OperatorDep,
    OperatorOrNot,
    SettingsDep,
)
from telerobot.server.api.requests import StrictRequest
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.autonomy import Mode
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed
from telerobot.server.control.limits import full_speed_stop_s, stopping
from telerobot.server.telemetry.stats import StreamTally

# A script's client (no connection of its own) is forgotten this long after its last
# request, unless it holds the lease (the setting rest_client_idle_s, 60 s by default):
# a script supervising a task is gone once it is forgotten, so it keeps itself present
# with its heartbeat.
# A script's lease is kept this long between absolute moves (a bounded move runs to its
# end under the server's supervision); increments get the 150 ms dead-man.
REST_LEASE_IDLE_S = 5.0

router = APIRouter(tags=["control"])


class LeaseRequest(StrictRequest):
    name: str = Field(
        "script",
        max_length=MAX_NAME,
        description=f"who is in control, as others see it ({RULE}; trimmed); the same"
        " name from the same address takes its own idle lease again (a script run twice)",
    )
    force: bool = Field(False, description="take control even if another client holds it")
    policy: bool = Field(
        False,
        description="this client is a learned policy (send a policy token, not the operator"
        " token): it drives under supervision once a person lets it, and any operator takes"
        " control from it at will (GET /autonomy)",
    )
    idle_timeout_s: float = Field(
        REST_LEASE_IDLE_S,
        gt=0,
        le=60,
        description="how long the lease is kept with no request between absolute moves"
        " (a script pausing); while it jogs (incremental moves) the dead-man's limit applies",
    )

    @field_validator("name")
    @classmethod
    def _plain_name(cls, name: str) -> str:
        problem = name_problem(name.strip())
        if problem:
            raise ValueError(problem)  # 422, saying the rule
        return name.strip()


class LeaseGranted(BaseModel):
    client_id: str = Field(description="send it as X-Client-Id with every command")


STOP_CATEGORY_TEXT = {
    StopCategory.UNCONTROLLED: "IEC 60204-1 stop category 0: power removed at once",
    StopCategory.CONTROLLED_THEN_UNPOWERED: (
        "IEC 60204-1 stop category 1: a controlled stop, power removed at rest"
    ),
    StopCategory.CONTROLLED_HOLDING: (
        "IEC 60204-1 stop category 2: a controlled stop; the drives brake the arm at their "
        "limit and stay powered, holding it where it stopped, so an operator can take "
        "control again without anyone at the controller. Every stop this server makes is "
        "one: lease lost or released, dead-man, e-stop (page, REST, /ws), force limit. "
        "It is no safety-rated stop: the controller's hardware e-stop (category 0) stays "
        "the one a person relies on"
    ),
}


class StoppingView(BaseModel):
    speed_m_s: float = Field(description="tool speed, straight line, worst direction")
    time_s: float = Field(description="from the stop to the arm at rest")
    distance_m: float = Field(description="tool travel in that time")
    after_silence_time_s: float = Field(
        description="from a silent controller's last message: the dead-man's detection, "
        "then the stop"
    )
    after_silence_distance_m: float = Field(
        description="tool travel in that time, at full speed until the stop"
    )


class CommandAgeView(BaseModel):
    """Executed commands' ages as they went to the driver (clients on the server's
    clock): the server's clock at its last age check, the driver's call next, minus
    the command's ``client_time``."""

    count: int = Field(description="executed commands with a known age, since the start")
    window: int = Field(description="the last this many, which p50 and p99 are of")
    p50: float | None = Field(description="ms; null before the first")
    p99: float | None = Field(description="ms; null before the first")
    max: float | None = Field(description="ms, the oldest since the start; null before the first")
    over_limit: int = Field(
        description="executed older than max_command_age_ms, since the start (the check"
        " before the driver refuses them: anything but 0 is a defect)"
    )


def command_ages(tally: StreamTally | None) -> CommandAgeView:
    """The figures of ``tally`` (None: a client with no executed command yet)."""
    values = tally.values() if tally is not None else np.empty(0)
    if tally is None or len(values) == 0:
        return CommandAgeView(count=0, window=0, p50=None, p99=None, max=None, over_limit=0)
    p50, p99 = np.percentile(values, [50, 99]).tolist()
    return CommandAgeView(
        count=tally.count,
        window=len(values),
        p50=p50,
        p99=p99,
        max=tally.largest,
        over_limit=tally.over,
    )


class SafetyView(BaseModel):
    estop: bool
    estop_reason: str
    force_limited: bool
    force_limited_arms: list[str] = Field(description="the arms stopped by their force limit")
    arm: str = Field(description="whose limits and stopping follow (?arm=; the first arm's)")
    controller: str | None  # name of the client in control
    halted: bool = Field(
        description="the dead-man stopped the arm; its controller keeps the lease for "
        "lease_grace_s, and a fresh command moves it again"
    )
    lease_note: str = Field(description="why control last changed hands or was lost")
    workspace_min: list[float]
    workspace_max: list[float]
    max_step_m: float
    max_step_rad: float
    max_speed_m_s: float
    force_limit_n: float
    contact_force_n: float = Field(description="a force above this marks a contact")
    contact_speed_m_s: float = Field(description="approach speed toward a recent contact")
    contact_memory_s: float = Field(description="how long a contact slows approaches")
    deadman_timeout_s: float
    lease_grace_s: float = Field(description="how long a lease outlives the dead-man's stop")
    max_command_age_ms: float = Field(
        description="a command sent longer ago than this (clients on the server's clock) "
        "is dropped, not executed late"
    )
    stale_commands_dropped: int = Field(description="commands dropped as too old, so far")
    executed_age_ms: CommandAgeView = Field(
        description="every executed command's age as it went to the driver, all clients"
    )
    executed_age_ms_client: CommandAgeView | None = Field(
        None,
        description="the same for the client asked for (?client=ID) alone, since it joined;"
        " null if none was asked for or none by that id is connected",
    )
    deadman_halts: int = Field(
        description="times the dead-man stopped the arm of a silent holder (lease kept), so far"
    )
    resumed_sessions: int = Field(
        description="sessions continued on a new connection after their link stalled, so far"
    )
    stop_category: int = Field(description="IEC 60204-1 stop category of every stop it makes")
    stop_category_text: str
    stop: str = Field(description="how the driver stops the arm")
    stop_decel_rad_s2: list[float] = Field(description="deceleration of a stop, per joint")
    stop_reaction_s: float = Field(description="from a stop to the deceleration starting")
    stopping: list[StoppingView] = Field(
        description="time and distance to rest from each tool speed (up to the limit) at "
        "the arm's current pose, in the worst direction"
    )
    stopping_full_speed_s: float = Field(
        description="time to rest from every joint at its speed limit (scripted moves)"
    )


class ControlSettings(BaseModel):
    scale: float = Field(description="master-to-slave motion scale for Cartesian increments")
    frame: WorkingFrame = Field(description="default frame of Cartesian increments")


class ControlSettingsUpdate(BaseModel):
    scale: float | None = None
    frame: WorkingFrame | None = None


def _stopping(guard: ArmGuard) -> list[StoppingView]:
    spec = guard.robot.stop_spec
    jacobian = guard.kinematics.jacobian(guard.robot.joints)
    return [
        StoppingView(
            speed_m_s=row.speed_m_s,
            time_s=row.time_s,
            distance_m=row.distance_m,
            after_silence_time_s=row.after_silence_time_s,
            after_silence_distance_m=row.after_silence_distance_m,
        )
        for row in stopping(guard.limits, spec, jacobian)
    ]


def _safety(
    decision: DecisionServer, arm: str | None = None, client_id: str | None = None
) -> SafetyView:
    """The safety state (one for every arm) and the limits of the arm named; with
    ``client_id``, that client's executed commands' ages too."""
    guard = decision.arm(arm) if arm else decision.arms[0]
    asked = decision.clients.known(client_id) if client_id else None
    s, lim = decision.state(), guard.limits
    spec = guard.robot.stop_spec
    return SafetyView(
        estop=s.estop,
        estop_reason=s.estop_reason,
        force_limited=s.force_limited,
        force_limited_arms=list(s.force_limited_arms),
        arm=guard.name,
        controller=s.lease_holder_name,
        halted=s.halted,
        lease_note=s.lease_note,
        workspace_min=lim.workspace_min.tolist(),
        workspace_max=lim.workspace_max.tolist(),
        max_step_m=lim.max_step_m,
        max_step_rad=lim.max_step_rad,
        max_speed_m_s=lim.max_speed_m_s,
        force_limit_n=lim.force_limit_n,
        contact_force_n=lim.contact_force_n,
        contact_speed_m_s=lim.contact_speed_m_s,
        contact_memory_s=lim.contact_memory_s,
        deadman_timeout_s=lim.deadman_timeout_s,
        lease_grace_s=lim.lease_grace_s,
        max_command_age_ms=lim.max_command_age_s * 1000,
        stale_commands_dropped=decision.ages.stale_dropped,
        executed_age_ms=command_ages(decision.ages.executed_ms),
        executed_age_ms_client=command_ages(asked.executed_age) if asked is not None else None,
        deadman_halts=decision.deadman_halts,
        resumed_sessions=decision.resumed_sessions,
        stop_category=int(spec.category),
        stop_category_text=STOP_CATEGORY_TEXT[spec.category],
        stop=spec.summary,
        stop_decel_rad_s2=spec.decel.tolist(),
        stop_reaction_s=spec.reaction_s,
        stopping=_stopping(guard),
        stopping_full_speed_s=full_speed_stop_s(spec),
    )


@router.post("/lease")
async def take_lease(
    request: Request,
    body: LeaseRequest,
    decision: DecisionDep,
    settings: SettingsDep,
    token: DriverDep,
    x_client_id: Annotated[str | None, Header()] = None,
) -> LeaseGranted:
    """Take control (the operator token is required). Between absolute moves the lease
    is kept ``idle_timeout_s`` without a request; while jogging (incremental moves) keep
    it with a heartbeat or a command at least every dead-man timeout (150 ms). A move
    waiting with ``wait`` counts as alive. Release it with ``DELETE /lease`` when done.
    A script run again (the same ``name`` from the same address) takes its earlier
    run's lease while that is idle, without ``force``; anyone else needs ``force``."""
    issued = decision.clients.policy_tokens.match(token)
    if x_client_id and issued and decision.clients.get(x_client_id).policy_token != issued.id:
        raise NotAllowed(f"client {x_client_id!r} did not join with this policy token")
    client = (
        decision.clients.get(x_client_id)
        if x_client_id
        else decision.join(
            body.name,
            token,
            idle_expiry_s=max(settings.rest_client_idle_s, body.idle_timeout_s),
            lease_idle_s=body.idle_timeout_s,
            source="rest",
            address=request.client.host if request.client else "",
            policy=body.policy,
        )
    )
    try:
        await decision.take_lease(client.id, force=body.force)
    except NotAllowed:
        if not x_client_id:  # refused: this request's client is not kept
            await decision.leave(client.id)
        raise
    return LeaseGranted(client_id=client.id)


@router.post("/lease/heartbeat")
async def heartbeat(client: DriverClientDep, decision: DecisionDep) -> SafetyView:
    """Keep the lease you hold; or, while a task you started holds it, keep yourself
    present as that task's supervisor (a script gone ``rest_client_idle_s`` stops its
    task). Anyone else gets 403."""
    decision.heartbeat(client.id)
    return _safety(decision)


@router.delete("/lease")
async def release_lease(client: DriverClientDep, decision: DecisionDep) -> SafetyView:
    if decision.lease_holder == client.id:
        await decision.release_lease(client.id)
    await decision.leave(client.id)
    return _safety(decision)


@router.get("/safety")
async def safety(
    decision: DecisionDep,
    operator: OperatorOrNot,
    arm: Annotated[
        str | None,
        Query(max_length=32, description="whose limits and stopping (default: the first arm)"),
    ] = None,
    client: Annotated[
        str | None,
        Query(
            max_length=64,
            description="a client id (its WELCOME's, or POST /lease's): its own executed"
            " commands' ages in executed_age_ms_client (with the operator token only)",
        ),
    ] = None,
) -> SafetyView:
    if client is not None and not operator:
        raise NotAllowed(
            "a client's own command ages (?client=) are the operator's to read: send the"
            " operator token, or leave out ?client= for everyone's"
        )
    return _safety(decision, arm, client)


@router.post("/safety/estop")
async def estop(request: Request, decision: DecisionDep) -> SafetyView:
    """Anyone may press the e-stop: motion stops and stays stopped until a reset."""
    who = request.client.host if request.client else "unknown"
    await decision.estop(None, f"e-stop pressed over REST from {who}", source="rest")
    return _safety(decision)


@router.post("/safety/reset")
async def reset(client: ClientDep, decision: DecisionDep) -> SafetyView:
    await decision.reset(client.id)
    return _safety(decision)


class AutonomyView(BaseModel):
    mode: Mode = Field(description="off (no policy), autonomous, paused or correcting")
    policy: str | None = Field(description="the policy's name")
    operator: str | None = Field(description="who corrected, paused or resumed it last")
    cause: str = Field(description="why the mode is what it is")
    rate_hz: float = Field(description="the policy's commands a second, as received")
    refused: int = Field(description="its commands refused while paused or corrected")
    interventions: int = Field(description="takeovers since the policy took control")


def _autonomy(decision: DecisionServer) -> AutonomyView:
    return AutonomyView.model_validate(decision.autonomy.state().as_dict())


@router.get("/autonomy")
async def autonomy(decision: DecisionDep) -> AutonomyView:
    """Who drives while a policy is connected. Take over with ``POST /lease`` (no
    ``force`` needed from a policy), hand back with ``DELETE /lease`` or ``resume``."""
    return _autonomy(decision)


@contextlib.asynccontextmanager
async def _supervisor(
    request: Request, decision: DecisionServer, x_client_id: str | None, token: str
) -> AsyncIterator[Client]:
    """The person acting on the autonomy: the client of ``X-Client-Id`` (one that took
    the lease, or a connection's), or, without it, a supervisor joined for this request
    alone: pausing or resuming a policy needs no lease of one's own."""
    if x_client_id:
        client = decision.clients.get(x_client_id)
        if client.policy:
            raise NotAllowed("only a person supervises a policy (the operator token)")
        decision.seen(client.id)
        yield client
        return
    host = request.client.host if request.client else ""
    client = decision.join("rest supervisor", token, source="rest", address=host)
    try:
        yield client
    finally:
        await decision.leave(client.id)


@router.post("/autonomy/pause")
async def pause_autonomy(
    request: Request,
    decision: DecisionDep,
    token: OperatorDep,
    x_client_id: Annotated[str | None, Header()] = None,
) -> AutonomyView:
    """Hold the policy still: its commands are refused until a person resumes it (the
    operator token; ``X-Client-Id`` optional: no lease is needed)."""
    async with _supervisor(request, decision, x_client_id, token) as client:
        await decision.pause(client.id)
    return _autonomy(decision)


@router.post("/autonomy/resume")
async def resume_autonomy(
    request: Request,
    decision: DecisionDep,
    token: OperatorDep,
    x_client_id: Annotated[str | None, Header()] = None,
) -> AutonomyView:
    """A person lets the policy drive, from where the arm is: the first time after it took
    control, and after every stop (the e-stop, once reset; a force stop; a pause; a lapse;
    the policy reconnecting). The operator token; ``X-Client-Id`` optional: no lease is
    needed. From a correction, control goes back to the policy."""
    async with _supervisor(request, decision, x_client_id, token) as client:
        await decision.resume_policy(client.id)
    return _autonomy(decision)


@router.get("/control")
async def control_settings(decision: DecisionDep) -> ControlSettings:
    return ControlSettings(scale=decision.scale, frame=decision.frame)


@router.put("/control")
async def update_control_settings(
    body: ControlSettingsUpdate, decision: DecisionDep, client: ClientDep
) -> ControlSettings:
    if decision.lease_holder != client.id:
        raise NotAllowed("take the control lease before changing scale or frame")
    if body.scale is not None:
        decision.scale = body.scale
    if body.frame is not None:
        decision.frame = body.frame
    return ControlSettings(scale=decision.scale, frame=decision.frame)
