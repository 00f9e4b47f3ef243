"""The HTTP edge: what every request passes before any route does work for it
(docs/architecture.md, rule 18, bounded everything at the edge).

In this order, each answered at once with problem+json and nothing read further:

1. ``Host`` must name this server (its configured host, loopback names, this
   machine's names and addresses, the TLS certificate's, ``allowed_hosts``): a page
   on another site that rebinds its DNS name to this address (DNS rebinding) gets 400.
   WebSocket handshakes too.
2. A state-changing request (POST, PUT, PATCH, DELETE) from a browser page of another
   origin (its ``Origin``) gets 403, and one that is neither JSON nor carries a header
   a cross-site form cannot set (``Authorization``, ``X-Telerobot-Client``) gets 415:
   a foreign page's ``text/plain`` POST cannot latch the e-stop or anything else.
3. A route that needs the operator token checks it before the body is read.
4. The body is bounded per route (``BODY_LIMITS``, else ``DEFAULT_BODY_LIMIT``):
   a ``Content-Length`` above it gets 413 before a byte is read; a body without one
   is read up to the limit and refused past it. Nothing unbounded is ever parsed, so
   a 50 MB body cannot hold the event loop (the e-stop's) for a minute.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from fastapi import FastAPI
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from telerobot.server.api.deps import OPERATOR_SCHEME, POLICY_SCHEME
from telerobot.server.errors import problem
from telerobot.server.security import bearer, origin_allowed, token_matches

log = logging.getLogger(__name__)

KIB = 1024
DEFAULT_BODY_LIMIT = 16 * KIB  # every command, lease, setting: a few hundred bytes
BODY_LIMITS: dict[str, int] = {
    # An SDP offer is 3–10 kB; 100 000 characters at most (the model's limit) plus
    # JSON escaping of its CR LF line ends.
    "/api/v1/webrtc/offer": 256 * KIB,
    "/api/v1/webrtc/answer": 256 * KIB,
    # Up to 60 captured 1280×720 board views, PNG or JPEG in base64 (~0.3 MB each).
    "/api/v1/calibration/intrinsics/views": 32 * KIB * KIB,
    "/api/v1/calibration/fit": 64 * KIB,  # clicked fiducials: a few hundred numbers
}
UNSAFE = frozenset({"POST", "PUT", "PATCH", "DELETE"})
CLIENT_HEADER = b"x-telerobot-client"  # any value: a header no cross-site form can set


@dataclass(frozen=True)
class RouteRule:
    """What the edge knows of one path: its pattern, which methods need the operator
    token, and its body limit. Taken from the OpenAPI schema, so it never drifts from
    the routes."""

    pattern: re.Pattern[str]
    operator_methods: frozenset[str]
    body_limit: int
    # Of those, the methods a policy token may use too (the lease, moves).
    policy_methods: frozenset[str] = frozenset()


def route_rules(schema: dict[str, Any]) -> list[RouteRule]:
    rules = []
    for path, operations in schema.get("paths", {}).items():
        regex = re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(path))

        def needing(scheme: str, operations: dict[str, Any] = operations) -> frozenset[str]:
            return frozenset(
                method.upper()
                for method, op in operations.items()
                if isinstance(op, dict)
                and any(scheme in requirement for requirement in op.get("security", ()))
            )

        rules.append(
            RouteRule(
                re.compile(f"^{regex}$"),
                needing(OPERATOR_SCHEME),
                BODY_LIMITS.get(path, DEFAULT_BODY_LIMIT),
                needing(POLICY_SCHEME),
            )
        )
    return rules


def _host_name(host_header: str) -> str:
    """``example.org:8000`` → ``example.org``; ``[::1]:8000`` → ``::1``."""
    host = host_header.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    if host.count(":") == 1:
        return host.split(":", 1)[0]
    return host


class Edge:
    """Pure ASGI middleware (no body buffering of its own beyond the route's limit)."""

    def __init__(
        self,
        app: ASGIApp,
        *,
        fastapi: FastAPI,
        allowed_hosts: Iterable[str],
        allowed_origins: Iterable[str],
        check_token: Callable[[str | None], bool],
        check_policy_token: Callable[[str | None], bool] = lambda _: False,
    ) -> None:
        self.app = app
        self.fastapi = fastapi
        self.allowed_hosts = {h.lower() for h in allowed_hosts}
        self.allowed_origins = list(allowed_origins)
        self.check_token = check_token
        self.check_policy_token = check_policy_token
        self._rules: list[RouteRule] | None = None

    # ------------------------------------------------------------ helpers
    def host_allowed(self, host_header: str | None) -> bool:
        return host_header is not None and _host_name(host_header) in self.allowed_hosts

    def _rule(self, path: str) -> RouteRule | None:
        if self._rules is None:
            self._rules = route_rules(self.fastapi.openapi())
        return next((r for r in self._rules if r.pattern.match(path)), None)

    async def _refuse(self, scope: Scope, send: Send, status: int, code: str, text: str) -> None:
        response = problem(status, code, text)
        response.headers["connection"] = "close"
        await response(scope, _no_body, send)

    # ------------------------------------------------------------ the middleware
    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = _headers(scope)
        if not self.host_allowed(headers.get(b"host", b"").decode("latin-1") or None):
            if scope["type"] == "websocket":
                await send({"type": "websocket.close", "code": 1008, "reason": "host not allowed"})
                return
            await self._refuse(
                scope,
                send,
                400,
                "host_not_allowed",
                "this server does not answer to that host name: use the address it printed, "
                "or add the name to allowed_hosts (TELEROBOT_ALLOWED_HOSTS)",
            )
            return
        if scope["type"] == "websocket" or scope["method"] not in UNSAFE:
            await self.app(scope, receive, send)
            return
        await self._unsafe(scope, receive, send, headers)

    async def _unsafe(
        self, scope: Scope, receive: Receive, send: Send, headers: dict[bytes, bytes]
    ) -> None:
        origin = headers.get(b"origin")
        if origin is not None and not origin_allowed(
            origin.decode("latin-1"),
            headers.get(b"host", b"").decode("latin-1"),
            self.allowed_origins,
        ):
            await self._refuse(
                scope,
                send,
                403,
                "origin_not_allowed",
                "requests from pages of other sites"
                " may not change anything here (add the origin to allowed_origins if it is"
                " yours)",
            )
            return
        content_type = headers.get(b"content-type", b"").split(b";")[0].strip().lower()
        if not (
            content_type == b"application/json"
            or b"authorization" in headers
            or CLIENT_HEADER in headers
        ):
            await self._refuse(
                scope,
                send,
                415,
                "json_required",
                "send 'Content-Type: application/json' (an empty body is fine), or the"
                " header 'X-Telerobot-Client: <your tool>', with every request that changes"
                " something",
            )
            return
        rule = self._rule(scope["path"])
        if rule is not None and scope["method"] in rule.operator_methods:
            token = bearer(headers.get(b"authorization", b"").decode("latin-1"))
            policy_may = scope["method"] in rule.policy_methods
            if not self.check_token(token) and not (policy_may and self.check_policy_token(token)):
                await self._refuse(
                    scope,
                    send,
                    403,
                    "not_allowed",
                    "a policy token cannot do this: it needs a person's operator token"
                    if self.check_policy_token(token)
                    else "this needs the operator token: send 'Authorization: Bearer <token>'",
                )
                return
        limit = rule.body_limit if rule is not None else DEFAULT_BODY_LIMIT
        length = headers.get(b"content-length")
        if length is not None:
            try:
                declared = int(length)
            except ValueError:
                declared = -1
            if declared < 0:
                await self._refuse(
                    scope, send, 400, "bad_request", "Content-Length is not a number"
                )
                return
            if declared > limit:
                await self._refuse(
                    scope, send, 413, "body_too_large", _too_large(limit, scope["path"])
                )
                return
        # Read the body here, bounded (a Content-Length may lie, or be absent).
        chunks: list[bytes] = []
        size = 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > limit:
                await self._refuse(
                    scope, send, 413, "body_too_large", _too_large(limit, scope["path"])
                )
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def _too_large(limit: int, path: str) -> str:
    return f"the body is larger than {limit} bytes, the most {path} takes"


async def _no_body() -> Message:
    return {"type": "http.request", "body": b"", "more_body": False}


def _headers(scope: Scope) -> dict[bytes, bytes]:
    # Last one wins for duplicates; names are already lower case in ASGI.
    out: dict[bytes, bytes] = {}
    for name, value in scope.get("headers", ()):
        out[name] = value
    return out


def install_edge(
    app: FastAPI, allowed_hosts: Iterable[str], allowed_origins: list[str], token: str
) -> None:
    app.add_middleware(
        Edge,
        fastapi=app,
        allowed_hosts=list(allowed_hosts),
        allowed_origins=allowed_origins,
        check_token=lambda candidate: token_matches(candidate, token),
        check_policy_token=lambda candidate: _policy_token_matches(app, candidate),
    )


def _policy_token_matches(app: FastAPI, candidate: str | None) -> bool:
    """Whether ``candidate`` is an issued policy token (none before the services run)."""
    services = getattr(app.state, "services", None)
    return (
        services is not None
        and services.decision.clients.policy_tokens.match(candidate) is not None
    )
