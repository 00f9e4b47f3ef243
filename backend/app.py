"""The FastAPI application: the HTTP edge, routers, and a lifespan that builds the
services (``backend/services.py``, the composition root) at start and stops them at
shutdown."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles
from starlette.routing import Match, Mount
from starlette.types import Scope

from telerobot.drivers.clock import Clock, MonotonicClock
from telerobot.server.api import (
    calibration,
    control,
    export,
    force,
    health,
    policy_tokens,
    recording_review,
    recordings,
    robot,
    tasks,
    telemetry,
    video,
    viewer,
    workcell,
)
from telerobot.server.edge import install_edge
from telerobot.server.errors import install_error_handlers
from telerobot.server.realtime import ws
from telerobot.server.security import allowed_host_names, operator_token, state_dir
from telerobot.server.services import (
    OperatorToken,
    Services,
    build_services,
    start_services,
    stop_services,
)
from telerobot.server.settings import Settings

log = logging.getLogger("telerobot")
API_PREFIXES = ("/api/", "/ws/")
STATIC = Path(__file__).parent / "static"
# The operator client, built from web/ by `make web` into the package (the wheel ships it).
WEB_DIST = Path(__file__).parent / "web"


def install_api_docs(app: FastAPI) -> None:
    """``/docs``: Swagger UI from the installed ``swagger-ui-bundle-v2`` package, not a
    CDN (a workcell's LAN often has no internet; FastAPI's default page was blank)."""
    from fastapi.openapi.docs import get_swagger_ui_html
    from swagger_ui_bundle import swagger_ui_path  # type: ignore[import-untyped]

    app.mount("/docs-assets", StaticFiles(directory=swagger_ui_path), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    async def api_docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="Telerobot API",
            swagger_js_url="/docs-assets/swagger-ui-bundle.js",
            swagger_css_url="/docs-assets/swagger-ui.css",
            swagger_favicon_url="/docs-assets/favicon-32x32.png",
        )


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


def services_of(app: FastAPI) -> Services:
    """The running application's services (for ``telerobot serve``'s start-up lines)."""
    services: Services = app.state.services
    return services


def create_app(
    settings: Settings | None = None, *, clock: Clock | None = None, record: str | None = None
) -> FastAPI:
    """``record``: start a recording of that name as soon as the server runs."""
    settings = settings or Settings()
    clock = clock or MonotonicClock()
    token, token_is_new = operator_token(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        services = build_services(settings, clock, OperatorToken(token, token_is_new))
        app.state.services = services
        app.openapi()  # made now, not on the first request (the edge reads it: ~0.1 s)
        await start_services(services)
        if record:
            services.recorder.start(record)
        try:
            yield
        finally:
            await stop_services(services)

    app = FastAPI(
        title="Telerobot",
        version="0.1.0",
        summary="Drive a robot arm from a browser, in stereo, with force feedback.",
        lifespan=lifespan,
        docs_url=None,  # served below from the package: it must work with no internet
        redoc_url=None,
    )
    install_api_docs(app)
    install_error_handlers(app)
    certificate = state_dir(settings) / "tls" / "cert.pem" if settings.tls else None
    install_edge(app, allowed_host_names(settings, certificate), settings.allowed_origins, token)
    api = APIRouter(prefix="/api/v1")
    for module in (
        health, robot, control, force, telemetry, video, workcell, calibration, viewer, recordings,
        recording_review, export, tasks, policy_tokens,
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
            log.warning("the operator page is not built (run `make web`): serving the status page")
            return FileResponse(STATIC / "index.html")

    return app
