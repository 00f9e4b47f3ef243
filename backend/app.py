"""The FastAPI application: routers, and a lifespan that opens the devices at start
and closes them at shutdown."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse

from backend.api import health, robot, workcell
from backend.devices import build_robot, build_workcell
from backend.errors import install_error_handlers
from backend.settings import Settings
from drivers.base import Robot, TelerobotError
from drivers.clock import Clock

log = logging.getLogger("telerobot")
STATIC = Path(__file__).parent / "static"


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


def create_app(settings: Settings | None = None, *, clock: Clock | None = None) -> FastAPI:
    settings = settings or Settings()

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        app.state.settings = settings
        app.state.workcell = build_workcell(settings)
        app.state.robot = build_robot(settings, clock)
        bring_up = asyncio.create_task(bring_up_robot(app.state.robot, settings.auto_initialize))
        app.state.robot_bring_up = bring_up
        try:
            yield
        finally:
            bring_up.cancel()
            with contextlib.suppress(asyncio.CancelledError, TelerobotError):
                await bring_up
            await app.state.robot.disconnect()

    app = FastAPI(
        title="Telerobot",
        version="0.1.0",
        summary="Drive a robot arm from a browser, in stereo, with force feedback.",
        lifespan=lifespan,
    )
    install_error_handlers(app)
    api = APIRouter(prefix="/api/v1")
    api.include_router(health.router)
    api.include_router(robot.router)
    api.include_router(workcell.router)
    app.include_router(api)

    @app.get("/", include_in_schema=False)
    async def status_page() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    return app
