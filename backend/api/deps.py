"""``Annotated`` dependency aliases: devices live on ``app.state``, never in globals.

Who may do what: reading is open to every client; changing anything needs the
operator token (``Authorization: Bearer …``); moving the robot needs the control
lease too (``X-Client-Id`` from ``POST /api/v1/lease``). The e-stop is open to all.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import Depends, Header, Request, Security
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from backend.control.decision import Client, DecisionServer, NotAllowed
from backend.realtime.priority import PriorityChannel
from backend.settings import Settings
from backend.telemetry.stats import Telemetry
from drivers.base import ForceSensor, Robot
from drivers.sim.workcell import Workcell


def from_state(name: str) -> Callable[[Request], Any]:
    """A dependency that reads ``app.state.<name>`` (its type is the alias's)."""

    def dependency(request: Request) -> Any:
        return getattr(request.app.state, name)

    dependency.__name__ = f"get_{name}"
    return dependency


RobotDep = Annotated[Robot, Depends(from_state("robot"))]
SettingsDep = Annotated[Settings, Depends(from_state("settings"))]
WorkcellDep = Annotated[Workcell, Depends(from_state("workcell"))]
DecisionDep = Annotated[DecisionServer, Depends(from_state("decision"))]
ForceDep = Annotated[ForceSensor, Depends(from_state("force"))]
PriorityDep = Annotated[PriorityChannel, Depends(from_state("priority"))]
TelemetryDep = Annotated[Telemetry, Depends(from_state("telemetry"))]


def bearer_token(authorization: Annotated[str | None, Header()] = None) -> str | None:
    if authorization and authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    return None


# Declared as a security scheme, so the OpenAPI schema says which operations need the
# token (``security: [{"OperatorToken": []}]``): the HTTP edge checks it there before
# a body is read, and /docs offers "Authorize".
OPERATOR_SCHEME = "OperatorToken"
operator_bearer = HTTPBearer(
    auto_error=False, scheme_name=OPERATOR_SCHEME, description="the operator token"
)


def require_operator(
    decision: DecisionDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(operator_bearer)],
) -> str:
    token = credentials.credentials.strip() if credentials is not None else None
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
