"""Errors as RFC 9457 problem+json with a message a person can act on."""

from __future__ import annotations

import asyncio

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from telerobot.drivers.base import (
    DeviceError,
    DriverUnavailable,
    InvalidCommand,
    NotReady,
    TelerobotError,
)

MAX_LISTED_ERRORS = 10  # a validation answer lists this many problems at most
# A client refused for going over a budget (429) gets its answer this late. A loop that
# repeats a refused request as fast as the server answers (one tokenless loop in
# bench.abuse: ~200 refusals a second) then asks at most 10 times a second on each
# connection, and the event loop that serves the e-stop no longer spends half a core
# answering it. Waiting costs the server nothing but the open connection, and those are
# capped per address and in all.
REFUSAL_DELAY_S = 0.1

# What the REST API answers for the drivers' errors (and their heirs): drivers know no
# HTTP. The server's own errors say theirs where they are defined (``http_status``).
DRIVER_STATUSES: dict[type[TelerobotError], int] = {
    InvalidCommand: 422,  # nothing moved: the request was wrong
    NotReady: 409,  # nothing moved: not in a state to accept it
    DeviceError: 503,  # the device or its link failed
    DriverUnavailable: 503,
}


def http_status(exc: TelerobotError) -> int:
    """The status for ``exc``: its class's (or an ancestor's) ``http_status``, else the
    nearest driver error's in ``DRIVER_STATUSES``, else 500."""
    for cls in type(exc).__mro__:
        status = vars(cls).get("http_status", DRIVER_STATUSES.get(cls))
        if isinstance(status, int):
            return status
    return 500


def problem(status: int, code: str, detail: str, **extra: object) -> JSONResponse:
    return JSONResponse(
        {
            "type": f"urn:telerobot:error:{code}",
            "title": code.replace("_", " "),
            "status": status,
            "detail": detail,
            **extra,
        },
        status_code=status,
        media_type="application/problem+json",
    )


def validation_problem(exc: RequestValidationError) -> JSONResponse:
    """422 saying where and what, never echoing the input back (a large body would
    come back whole: 105 MB for a 50 MB one)."""
    errors = [
        {
            "loc": [str(part)[:64] for part in e.get("loc", ())][:8],
            "msg": str(e.get("msg", ""))[:200],
            "type": str(e.get("type", ""))[:64],
        }
        for e in exc.errors()[:MAX_LISTED_ERRORS]
    ]
    first = errors[0] if errors else {"loc": [], "msg": "invalid request"}
    where = ".".join(str(p) for p in first["loc"])
    return problem(
        422,
        "invalid_request",
        f"{where}: {first['msg']}" if where else str(first["msg"]),
        errors=errors,
        error_count=len(exc.errors()),
    )


def install_error_handlers(app: FastAPI) -> None:
    async def on_telerobot_error(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, TelerobotError)
        status = http_status(exc)
        answer = problem(status, exc.code, str(exc))
        if status == 429:
            await asyncio.sleep(REFUSAL_DELAY_S)
            answer.headers["Retry-After"] = "1"  # budgets refill within a second
        return answer

    async def on_validation_error(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return validation_problem(exc)

    app.add_exception_handler(TelerobotError, on_telerobot_error)
    app.add_exception_handler(RequestValidationError, on_validation_error)
