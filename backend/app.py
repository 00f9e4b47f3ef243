"""The FastAPI application: routers, and a lifespan that opens the devices at start
and closes them at shutdown."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles
from starlette.routing import Match, Mount
from starlette.types import Scope

from backend.api import (
    calibration,
    control,
    force,
    health,
    robot,
    telemetry,
    video,
    viewer,
    workcell,
)
from backend.control.decision import DecisionServer
from backend.control.limits import SafetyLimits
from backend.devices import build_force_sensor, build_robot, build_workcell
from backend.edge import install_edge
from backend.errors import install_error_handlers
from backend.media.supervisor import MediaSupervisor
from backend.realtime import ws
from backend.realtime.hub import RealtimeHub
from backend.realtime.priority import PriorityChannel
from backend.security import allowed_host_names, operator_token, state_dir
from backend.settings import Settings
from backend.telemetry.stats import Telemetry
from backend.viewer3d import Workcell3DView
from calibration.model import CalibrationError
from calibration.store import CalibrationStore
from drivers.base import DeviceError, Robot, TelerobotError
from drivers.clock import Clock, MonotonicClock
from drivers.robot.puma560.kinematics import Puma560Kinematics, tool_transform

log = logging.getLogger("telerobot")
API_PREFIXES = ("/api/", "/ws/")
STATIC = Path(__file__).parent / "static"
WEB_DIST = Path(__file__).resolve().parents[1] / "web" / "dist"  # built by `make web`


async def bring_up_robot(robot: Robot, initialize: bool) -> None:
    """Connect and initialise; a failure leaves the robot in ERROR with its reason
    (shown by the state endpoint) and the server keeps serving."""
    try:
        await robot.connect()
        if initialize:
            await robot.initialize()
        log.info("robot %s is %s", robot.name, robot.status)
    except TelerobotError as exc:
        log.error("robot %s could not be brought up: %s", robot.name, exc)


def load_calibration(settings: Settings) -> tuple[CalibrationStore, str | None]:
    """The saved calibration; a file that cannot be read is kept as it is, reported,
    and the cameras' ground truth stands in."""
    rig = settings.rig_name
    store = CalibrationStore(state_dir(settings) / f"calibration-{rig}.json", rig)
    try:
        return store.load(), None
    except CalibrationError as exc:
        log.error("%s", exc)
        return store, str(exc)


def start_viewer(settings: Settings, s: Any) -> tuple[Workcell3DView | None, str | None]:
    """The 3D view, if on; a view that cannot start (port taken) is reported, and the
    server runs without it."""
    if not settings.viewer:
        return None, "the 3D view is off (setting viewer)"
    try:
        view = Workcell3DView(
            settings.host,
            settings.viewer_port,
            s.workcell,
            s.robot,
            s.force,
            s.calibration,
            Puma560Kinematics(tool_transform(settings.tool_length)),
        )
    except (OSError, ImportError) as exc:
        log.error("the 3D view cannot start on port %s: %s", settings.viewer_port, exc)
        return None, f"the 3D view cannot start on port {settings.viewer_port}: {exc}"
    view.start()
    return view, None


class ClientFiles(Mount):
    """The operator client's files at ``/``, but never for the API's or /ws's paths: a
    GET on a POST-only API path answers 405 from its route, an unknown API path 404,
    rather than the client's files answering 404 for everything."""

    def __init__(self, path: str, files: StaticFiles) -> None:
        super().__init__(path, app=files, name="web")

    def matches(self, scope: Scope) -> tuple[Match, Scope]:
        path = scope.get("path", "")
        if path.startswith(API_PREFIXES) or path in ("/api", "/ws"):
            return Match.NONE, {}
        return super().matches(scope)


def create_app(settings: Settings | None = None, *, clock: Clock | None = None) -> FastAPI:
    settings = settings or Settings()
    clock = clock or MonotonicClock()
    token, token_is_new = operator_token(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        s = app.state
        s.settings, s.token, s.token_is_new = settings, token, token_is_new
        s.telemetry = Telemetry()
        s.workcell = build_workcell(settings)
        s.calibration, s.calibration_error = load_calibration(settings)
        s.intrinsics = {}  # camera → (K, dist) from a ChArUco capture, until its fit
        s.robot = build_robot(settings, clock)
        s.force = build_force_sensor(settings, s.robot, s.workcell)
        limits = SafetyLimits(
            force_limit_n=settings.force_limit_n,
            deadman_timeout_s=settings.deadman_timeout_s,
            max_speed_m_s=settings.max_speed_m_s,
            contact_speed_m_s=settings.contact_speed_m_s,
        )
        # The DecisionServer's own model (same tool): Pinocchio data is per instance.
        kinematics = Puma560Kinematics(tool_transform(settings.tool_length))
        s.decision = DecisionServer(
            s.robot,
            kinematics=kinematics,
            clock=clock,
            operator_token=token,
            limits=limits,
            force=s.force,
        )
        s.decision.start()  # the force limit and the dead-man, whatever transports run
        s.hub = RealtimeHub(
            s.robot, s.decision, s.force, s.telemetry, clock, state_rate_hz=settings.state_rate_hz
        )
        s.hub.start()
        try:
            s.priority = PriorityChannel(
                settings.host, settings.priority_port, s.hub, s.decision, s.force
            )
        except OSError as exc:
            await s.hub.stop()
            await s.decision.stop()
            raise DeviceError(
                f"the priority channel cannot listen on {settings.host}:{settings.priority_port}"
                f" ({exc.strerror}): set TELEROBOT_PRIORITY_PORT or --priority-port"
            ) from None
        s.priority.start()
        s.force.start()
        s.viewer, s.viewer_error = start_viewer(settings, s)
        s.alignments = {}
        s.media = MediaSupervisor(settings, s.robot) if settings.video else None
        if s.media is not None:
            await s.media.start()
        bring_up = asyncio.create_task(bring_up_robot(s.robot, settings.auto_initialize))
        try:
            yield
        finally:
            bring_up.cancel()
            with contextlib.suppress(asyncio.CancelledError, TelerobotError):
                await bring_up
            s.force.stop()
            if s.viewer is not None:
                await s.viewer.stop()
            if s.media is not None:
                await s.media.stop()
            await s.priority.stop()
            await s.hub.stop()
            await s.decision.stop()
            await s.robot.disconnect()

    app = FastAPI(
        title="Telerobot",
        version="0.1.0",
        summary="Drive a robot arm from a browser, in stereo, with force feedback.",
        lifespan=lifespan,
    )
    app.state.token, app.state.token_is_new = token, token_is_new
    install_error_handlers(app)
    certificate = state_dir(settings) / "tls" / "cert.pem" if settings.tls else None
    install_edge(app, allowed_host_names(settings, certificate), settings.allowed_origins, token)
    api = APIRouter(prefix="/api/v1")
    for module in (
        health, robot, control, force, telemetry, video, workcell, calibration, viewer
    ):  # fmt: skip
        api.include_router(module.router)
    app.include_router(api)
    app.include_router(ws.router)

    @app.get("/status", include_in_schema=False)
    async def status_page() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    if (WEB_DIST / "index.html").is_file():
        # The operator client; mounted last, so the API and /ws routes win.
        app.router.routes.append(ClientFiles("/", StaticFiles(directory=WEB_DIST, html=True)))
    else:

        @app.get("/", include_in_schema=False)
        async def no_client() -> FileResponse:
            log.warning("web/dist is missing (run `make web`): serving the status page")
            return FileResponse(STATIC / "index.html")

    return app
