"""``Annotated`` dependency aliases: devices live on ``app.state``, never in globals.

Who may do what: reading is open to every client; changing anything needs the
operator token (``Authorization: Bearer …``); moving the robot needs the control
lease too (``X-Client-Id`` from ``POST /api/v1/lease``). The e-stop is open to all.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request

from backend.control.decision import Client, DecisionServer, NotAllowed
from backend.settings import Settings
from backend.telemetry.stats import Telemetry
from drivers.base import ForceSensor, Robot
from drivers.sim.workcell import Workcell


def get_robot(request: Request) -> Robot:
    robot: Robot = request.app.state.robot
    return robot


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_workcell(request: Request) -> Workcell:
    workcell: Workcell = request.app.state.workcell
    return workcell


def get_decision(request: Request) -> DecisionServer:
    decision: DecisionServer = request.app.state.decision
    return decision


def get_force(request: Request) -> ForceSensor:
    force: ForceSensor = request.app.state.force
    return force


def get_telemetry(request: Request) -> Telemetry:
    telemetry: Telemetry = request.app.state.telemetry
    return telemetry


RobotDep = Annotated[Robot, Depends(get_robot)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
WorkcellDep = Annotated[Workcell, Depends(get_workcell)]
DecisionDep = Annotated[DecisionServer, Depends(get_decision)]
ForceDep = Annotated[ForceSensor, Depends(get_force)]
TelemetryDep = Annotated[Telemetry, Depends(get_telemetry)]


def bearer_token(authorization: Annotated[str | None, Header()] = None) -> str | None:
    if authorization and authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    return None


def require_operator(
    decision: DecisionDep, token: Annotated[str | None, Depends(bearer_token)]
) -> str:
    if not decision.check_token(token):
        raise NotAllowed("this needs the operator token: send 'Authorization: Bearer <token>'")
    assert token is not None
    return token


def current_client(
    decision: DecisionDep,
    _token: Annotated[str, Depends(require_operator)],
    x_client_id: Annotated[str | None, Header()] = None,
) -> Client:
    if not x_client_id:
        raise NotAllowed("send the X-Client-Id header you got from POST /api/v1/lease")
    client = decision.client(x_client_id)
    decision.seen(client.id)
    return client


OperatorDep = Annotated[str, Depends(require_operator)]
ClientDep = Annotated[Client, Depends(current_client)]
