"""``/ws``: the real-time protocol over a WebSocket (layouts in ``messages``, session
logic in ``session``, docs/protocol.md). This module is the framing: origin check,
HELLO within 5 s, one binary message per WebSocket message, the per-connection rate
limit, closing a client that sends nothing but garbage, and closing a connection at
once when its session resumes on another.
"""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from telerobot.drivers.base import TelerobotError
from telerobot.protocol import messages as m
from telerobot.protocol.names import client_name
from telerobot.server.api.deps import ServicesDep
from telerobot.server.realtime.ratelimit import MALFORMED_COST, MalformedRun, TokenBucket
from telerobot.server.realtime.session import Session, error
from telerobot.server.security import origin_allowed

log = logging.getLogger(__name__)
router = APIRouter()

HELLO_TIMEOUT_S = 5.0
# The close of a connection whose session resumed on another (docs/protocol.md), and
# how long its peer has to answer it before the socket is closed anyway (a stalled
# link's peer will not, and a client resuming in a loop would pile them up).
SUPERSEDED_CODE = 4001
SUPERSEDED_REASON = "this session resumed on a new connection"
SUPERSEDED_CLOSE_S = 1.0


class Reader:
    """The handler's task while it waits for its peer: a resume that supersedes the
    connection stops that wait at once (``stop``). A message being carried out is not
    interrupted: the loop sees the connection closed after it."""

    def __init__(self) -> None:
        self.task = asyncio.current_task()
        self.waiting = False

    async def stop(self) -> None:
        if self.waiting and self.task is not None:
            self.task.cancel()


@router.websocket("/ws")
async def realtime(websocket: WebSocket, services: ServicesDep) -> None:
    if not origin_allowed(
        websocket.headers.get("origin"),
        websocket.headers.get("host"),
        services.settings.allowed_origins,
    ):
        log.warning("refused /ws from origin %s", websocket.headers.get("origin"))
        await websocket.close(code=1008, reason="origin not allowed")
        return
    hub, decision = services.hub, services.decision
    peer = websocket.client
    bucket = services.ws_limits.connect(peer.host if peer else "", hub.clock.now())
    if bucket is None:  # reconnecting in a loop: refused before any work
        await websocket.close(code=1013, reason="too many connections from your address")
        return
    await websocket.accept()
    # The name the client gives itself (``/ws?name=``, telerobot/protocol/names.py), shown
    # wherever control is listed; without one, its address.
    asked = websocket.query_params.get("name")
    try:
        name = client_name(asked) if asked is not None else None
    except TelerobotError as exc:
        await websocket.send_bytes(error(0, exc.code, f"name: {exc}"))
        reason = f"name: {exc}".encode()[:120].decode(errors="ignore")  # (123 bytes at most)
        await websocket.close(code=1008, reason=reason)
        return
    reader = Reader()
    try:
        hello = await asyncio.wait_for(websocket.receive_bytes(), HELLO_TIMEOUT_S)
        session = Session.open(
            hello,
            decision=decision,
            hub=hub,
            peer=name or (f"ws {peer.host}:{peer.port}" if peer else "ws"),
            send=websocket.send_bytes,
            address=peer.host if peer else "",
            close_transport=reader.stop,
        )
    except (TimeoutError, m.MalformedMessage, KeyError) as exc:
        reason = "no HELLO within 5 s" if isinstance(exc, TimeoutError) else str(exc)
        await websocket.send_bytes(error(0, "malformed", reason))
        await websocket.close(code=1002, reason=reason[:120])
        return
    except TelerobotError as exc:  # the server is full
        await websocket.send_bytes(error(0, exc.code, str(exc)))
        await websocket.close(code=1013, reason=str(exc)[:120])
        return
    except WebSocketDisconnect:
        return
    conn = session.conn
    if conn.operator:
        # The token's holder gets a budget of its own: the address's is shared with
        # whoever else is there (a NAT, this machine), and a tokenless flood from the
        # same address must not make the operator's commands wait and go stale.
        bucket = TokenBucket()
    for message in session.welcome:  # WELCOME, then an ARM for each arm
        conn.reply(message)
    session.attach()
    garbage = MalformedRun()
    try:
        while not conn.closed:
            reader.waiting = True
            frame = await websocket.receive()
            if frame["type"] == "websocket.disconnect":
                break
            wait = bucket.take(hub.clock.now())
            if wait > 0:  # over its rate: read nothing more until it is back within it
                await hub.clock.sleep(wait)
            reader.waiting = False
            data = frame.get("bytes")
            if data is None:
                conn.reply(error(0, "malformed", "binary messages only (see docs/protocol.md)"))
                ok = False
            else:
                ok = await session.receive(data, hub.clock.now())
            if not ok:  # garbage pays more: its cost is taken before the next read
                bucket.take(hub.clock.now(), MALFORMED_COST - 1.0)
            if garbage.note(not ok):
                reason = f"{garbage.limit} malformed messages in a row: closing"
                await conn.close()  # its sender first: one writer on the socket
                await websocket.send_bytes(error(0, "malformed", reason))
                await websocket.close(code=1008, reason=reason)
                break
    except WebSocketDisconnect:
        pass
    except asyncio.CancelledError:
        if not session.superseded:
            raise
        if reader.task is not None:
            reader.task.uncancel()  # stopped by the resume (Reader.stop), not shut down
    finally:
        if session.superseded:
            await close_superseded(websocket)
        await session.close()


_closing: set[asyncio.Future[None]] = set()  # kept until done (the loop holds tasks weakly)


async def close_superseded(websocket: WebSocket) -> None:
    """The close frame, and a short wait for the peer's answer; then the handler ends
    and the server closes the socket whether it answered or not. (The websockets
    library's close waits up to 10 s for the peer, and a cancelled one still does.)"""
    closing = asyncio.ensure_future(websocket.close(SUPERSEDED_CODE, SUPERSEDED_REASON))
    _closing.add(closing)
    closing.add_done_callback(_closed)
    await asyncio.wait({closing}, timeout=SUPERSEDED_CLOSE_S)


def _closed(closing: asyncio.Future[None]) -> None:
    _closing.discard(closing)
    if not closing.cancelled():
        closing.exception()  # the peer already gone: nothing to say
