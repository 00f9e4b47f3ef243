"""Errors as RFC 9457 problem+json with a message a person can act on."""

from __future__ import annotations

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse

from telerobot.drivers.base import (
    TelerobotError,
)

MAX_LISTED_ERRORS = 10  # a validation answer lists this many problems at most


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
        return problem(exc.http_status, exc.code, str(exc))

    async def on_validation_error(_request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        return validation_problem(exc)

    app.add_exception_handler(TelerobotError, on_telerobot_error)
    app.add_exception_handler(RequestValidationError, on_validation_error)
