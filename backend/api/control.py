"""The control lease, safety (e-stop, limits) and motion settings (scale, frame)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request
from pydantic import BaseModel, Field

from backend.api.deps import ClientDep, DecisionDep, OperatorDep
from backend.control.decision import NotAllowed
from drivers.base import WorkingFrame

router = APIRouter(tags=["control"])


class LeaseRequest(BaseModel):
    name: str = Field("script", max_length=64)
    force: bool = Field(False, description="take control even if another client holds it")


class LeaseGranted(BaseModel):
    client_id: str = Field(description="send it as X-Client-Id with every command")


class SafetyView(BaseModel):
    estop: bool
    estop_reason: str
    force_limited: bool
    controller: str | None  # name of the client in control
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


class ControlSettings(BaseModel):
    scale: float = Field(description="master-to-slave motion scale for Cartesian increments")
    frame: WorkingFrame = Field(description="default frame of Cartesian increments")


class ControlSettingsUpdate(BaseModel):
    scale: float | None = None
    frame: WorkingFrame | None = None


def _safety(decision: DecisionDep) -> SafetyView:
    s, lim = decision.state(), decision.limits
    return SafetyView(
        estop=s.estop,
        estop_reason=s.estop_reason,
        force_limited=s.force_limited,
        controller=s.lease_holder_name,
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
    )


@router.post("/lease")
async def take_lease(
    body: LeaseRequest,
    decision: DecisionDep,
    token: OperatorDep,
    x_client_id: Annotated[str | None, Header()] = None,
) -> LeaseGranted:
    """Take control (the operator token is required). Keep it with a heartbeat at
    least every dead-man timeout, or any command; a move waiting with ``wait``
    counts as alive."""
    client = decision.client(x_client_id) if x_client_id else decision.join(body.name, token)
    await decision.take_lease(client.id, force=body.force)
    return LeaseGranted(client_id=client.id)


@router.post("/lease/heartbeat")
async def heartbeat(client: ClientDep, decision: DecisionDep) -> SafetyView:
    if decision.lease_holder != client.id:
        raise NotAllowed("you do not hold the lease (it may have lapsed: take it again)")
    return _safety(decision)


@router.delete("/lease")
async def release_lease(client: ClientDep, decision: DecisionDep) -> SafetyView:
    if decision.lease_holder == client.id:
        await decision.release_lease(client.id)
    await decision.leave(client.id)
    return _safety(decision)


@router.get("/safety")
async def safety(decision: DecisionDep) -> SafetyView:
    return _safety(decision)


@router.post("/safety/estop")
async def estop(request: Request, decision: DecisionDep) -> SafetyView:
    """Anyone may press the e-stop: motion stops and stays stopped until a reset."""
    who = request.client.host if request.client else "unknown"
    await decision.estop(None, f"e-stop pressed over REST from {who}")
    return _safety(decision)


@router.post("/safety/reset")
async def reset(client: ClientDep, decision: DecisionDep) -> SafetyView:
    await decision.reset(client.id)
    return _safety(decision)


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
