"""Typed ``Annotated`` dependencies: the only way routers reach the services
(docs/architecture.md, rule 13). The services are built once by ``backend/services.py`` and
kept on the application; nothing here is a module global.

Who may do what: reading is open to every client; changing anything needs the
operator token (``Authorization: Bearer …``); moving the robot needs the control
lease too (``X-Client-Id`` from ``POST /api/v1/lease``). The e-stop is open to all.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Header, Query, Security
from fastapi.requests import HTTPConnection
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from telerobot.drivers.base import ForceSensor
from telerobot.drivers.sim.workcell import Workcell
from telerobot.server.control.clients import Client
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed
from telerobot.server.devices import ArmDevices
from telerobot.server.media.media_server import MediaServerSupervisor
from telerobot.server.media.supervisor import MediaSupervisor, MediaUnavailable
from telerobot.server.realtime.hub import RealtimeHub
from telerobot.server.realtime.priority import PriorityChannel
from telerobot.server.security import bearer
from telerobot.server.services import Alignments, CalibrationRecord, Intrinsics, Services, Viewer3D
from telerobot.server.settings import Settings
from telerobot.server.telemetry.stats import Telemetry


def get_services(connection: HTTPConnection) -> Services:
    """The services of this application (HTTP requests and WebSockets alike)."""
    services: Services = connection.app.state.services
    return services


ServicesDep = Annotated[Services, Depends(get_services)]


def _settings(s: ServicesDep) -> Settings:
    return s.settings


def _arm(
    s: ServicesDep,
    arm: Annotated[
        str | None,
        Query(
            max_length=32,
            description="which arm (GET /robot/arms lists them); needed on a server with"
            " two arms or more, where a call without one is refused with their names",
        ),
    ] = None,
) -> ArmDevices:
    return s.arms[s.decision.arm(arm).index - 1]


def _workcell(s: ServicesDep) -> Workcell:
    return s.workcell


def _decision(s: ServicesDep) -> DecisionServer:
    return s.decision


def _force(arm: ArmDevices = Depends(_arm)) -> ForceSensor:  # noqa: B008 (FastAPI's way)
    """The force sensor of the arm ``?arm=`` names (the only one's if it names none)."""
    return arm.force


def _priority(s: ServicesDep) -> PriorityChannel:
    return s.priority


def _telemetry(s: ServicesDep) -> Telemetry:
    return s.telemetry


def _hub(s: ServicesDep) -> RealtimeHub:
    return s.hub


def _calibration(s: ServicesDep) -> CalibrationRecord:
    return s.calibration


def _intrinsics(s: ServicesDep) -> Intrinsics:
    return s.intrinsics


def _alignments(s: ServicesDep) -> Alignments:
    return s.alignments


def _viewer(s: ServicesDep) -> Viewer3D:
    return s.viewer


def _media_or_none(s: ServicesDep) -> MediaSupervisor | None:
    return s.media


def _media(s: ServicesDep) -> MediaSupervisor:
    if s.media is None:
        raise MediaUnavailable("video is turned off on this server (setting video = false)")
    return s.media


def _media_server(s: ServicesDep) -> MediaServerSupervisor | None:
    return s.media_server


SettingsDep = Annotated[Settings, Depends(_settings)]
# The arm a call names with ``?arm=`` (the only one if it names none; refused if the
# server has more): docs/arms.md.
ArmDep = Annotated[ArmDevices, Depends(_arm)]
WorkcellDep = Annotated[Workcell, Depends(_workcell)]
DecisionDep = Annotated[DecisionServer, Depends(_decision)]
ForceDep = Annotated[ForceSensor, Depends(_force)]
PriorityDep = Annotated[PriorityChannel, Depends(_priority)]
TelemetryDep = Annotated[Telemetry, Depends(_telemetry)]
HubDep = Annotated[RealtimeHub, Depends(_hub)]
CalibrationDep = Annotated[CalibrationRecord, Depends(_calibration)]
IntrinsicsDep = Annotated[Intrinsics, Depends(_intrinsics)]
AlignmentsDep = Annotated[Alignments, Depends(_alignments)]
ViewerDep = Annotated[Viewer3D, Depends(_viewer)]
MediaOrNoneDep = Annotated[MediaSupervisor | None, Depends(_media_or_none)]
MediaDep = Annotated[MediaSupervisor, Depends(_media)]
MediaServerDep = Annotated[MediaServerSupervisor | None, Depends(_media_server)]


def bearer_token(authorization: Annotated[str | None, Header()] = None) -> str | None:
    return bearer(authorization)


# Declared as security schemes, so the OpenAPI schema says which operations need a
# token (``security: [{"OperatorToken": []}]``; ``[{"OperatorToken": []}, {"PolicyToken":
# []}]`` where a policy token is taken too): the HTTP edge checks it there before a body
# is read, and /docs offers "Authorize".
OPERATOR_SCHEME = "OperatorToken"
POLICY_SCHEME = "PolicyToken"
operator_bearer = HTTPBearer(
    auto_error=False, scheme_name=OPERATOR_SCHEME, description="the operator token"
)
policy_bearer = HTTPBearer(
    auto_error=False,
    scheme_name=POLICY_SCHEME,
    description="a policy token (it can only drive, under supervision: docs/lerobot.md)",
)


def require_operator(
    decision: DecisionDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(operator_bearer)],
) -> str:
    token = credentials.credentials.strip() if credentials is not None else None
    if not decision.clients.check_token(token):
        if decision.clients.policy_tokens.match(token) is not None:
            raise NotAllowed("a policy token cannot do this: it needs a person's operator token")
        raise NotAllowed("this needs the operator token: send 'Authorization: Bearer <token>'")
    assert token is not None
    return token


def require_driver(
    decision: DecisionDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Security(operator_bearer)],
    _policy: Annotated[HTTPAuthorizationCredentials | None, Security(policy_bearer)],
) -> str:
    """The operator token or a policy token (routes a policy may use: the lease, moves)."""
    token = credentials.credentials.strip() if credentials is not None else None
    if (
        not decision.clients.check_token(token)
        and decision.clients.policy_tokens.match(token) is None
    ):
        raise NotAllowed(
            "this needs the operator token (or a policy token): send"
            " 'Authorization: Bearer <token>'"
        )
    assert token is not None
    return token


async def current_client(
    decision: DecisionDep,
    _token: Annotated[str, Depends(require_operator)],
    x_client_id: Annotated[str | None, Header()] = None,
) -> AsyncIterator[Client]:
    if not x_client_id:
        raise NotAllowed("send the X-Client-Id header you got from POST /api/v1/lease")
    client = decision.clients.get(x_client_id)
    if client.policy:
        raise NotAllowed("a policy's client cannot do this: it is a person's")
    decision.seen(client.id)
    async with _in_flight(client):
        yield client


@contextlib.asynccontextmanager
async def _in_flight(client: Client) -> AsyncIterator[None]:
    """A script's request in flight keeps its lease alive, however long it takes (a
    task's first read of its recording spawns a reader: seconds on a cold machine, past
    the lease's idle timeout)."""
    client.busy += 1
    try:
        yield
    finally:
        client.busy -= 1


async def current_driver(
    decision: DecisionDep,
    token: Annotated[str, Depends(require_driver)],
    x_client_id: Annotated[str | None, Header()] = None,
) -> AsyncIterator[Client]:
    """The client of a route a policy may use: with a policy token, only that token's own
    policy client."""
    if not x_client_id:
        raise NotAllowed("send the X-Client-Id header you got from POST /api/v1/lease")
    client = decision.clients.get(x_client_id)
    issued = decision.clients.policy_tokens.match(token)
    if issued is not None and client.policy_token != issued.id:
        raise NotAllowed(f"client {x_client_id!r} did not join with this policy token")
    decision.seen(client.id)
    async with _in_flight(client):
        yield client


OperatorDep = Annotated[str, Depends(require_operator)]


def is_operator(decision: DecisionDep, token: Annotated[str | None, Depends(bearer_token)]) -> bool:
    """Whether the request carries the operator token (looked at, not required)."""
    return decision.clients.check_token(token)


OperatorOrNot = Annotated[bool, Depends(is_operator)]
DriverDep = Annotated[str, Depends(require_driver)]
ClientDep = Annotated[Client, Depends(current_client)]
# A client on a route a policy may use too (the lease, moves): docs/lerobot.md.
DriverClientDep = Annotated[Client, Depends(current_driver)]
