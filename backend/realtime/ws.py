"""``/ws``: the binary real-time channel (layouts in ``messages``, docs/protocol.md).

The first message must be HELLO (with the operator token to be able to take
control; without it the client is an observer). Every later message is decoded,
checked and handed to the DecisionServer; anything malformed, unknown, of the wrong
size or carrying NaN gets an ERROR back and nothing moves; the connection and the
server stay up.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import numpy as np
from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from backend.control.decision import Applied, DecisionServer
from backend.realtime import messages as m
from backend.realtime.hub import Connection, RealtimeHub
from backend.realtime.ratelimit import MalformedRun, TokenBucket
from backend.security import origin_allowed
from drivers.base import TelerobotError, WorkingFrame

log = logging.getLogger(__name__)
router = APIRouter()

HELLO_TIMEOUT_S = 5.0
FRAMES: dict[int, WorkingFrame] = {
    m.Frame.BASE: WorkingFrame.BASE,
    m.Frame.WRIST: WorkingFrame.WRIST,
    m.Frame.TOOL: WorkingFrame.TOOL,
}


def check_hello(data: bytes) -> dict[str, Any]:
    """The first message's fields, if it is a HELLO this server speaks."""
    msg, fields, _ = m.decode(data)
    if msg is not m.HELLO:
        raise m.MalformedMessage(f"the first message must be HELLO, got {msg.name}")
    version = int(fields["version"])
    if version != m.PROTOCOL_VERSION:
        raise m.MalformedMessage(
            f"protocol version {version} is not spoken here: this server speaks"
            f" {m.PROTOCOL_VERSION} (update the client)"
        )
    return dict(fields)


def error(seq: int, code: str, text: str) -> bytes:
    return m.encode(
        m.ERROR, seq, m.ERROR_CODES.get(code, m.ERROR_CODES["telerobot_error"]), text=text
    )


@router.websocket("/ws")
async def realtime(websocket: WebSocket) -> None:
    app = websocket.app
    settings = app.state.settings
    if not origin_allowed(
        websocket.headers.get("origin"), websocket.headers.get("host"), settings.allowed_origins
    ):
        log.warning("refused /ws from origin %s", websocket.headers.get("origin"))
        await websocket.close(code=1008, reason="origin not allowed")
        return
    await websocket.accept()
    hub: RealtimeHub = app.state.hub
    decision: DecisionServer = app.state.decision
    try:
        hello = await asyncio.wait_for(websocket.receive_bytes(), HELLO_TIMEOUT_S)
        fields = check_hello(hello)
    except (TimeoutError, m.MalformedMessage, KeyError) as exc:
        reason = "no HELLO within 5 s" if isinstance(exc, TimeoutError) else str(exc)
        await websocket.send_bytes(error(0, "malformed", reason))
        await websocket.close(code=1002, reason=reason[:120])
        return
    except WebSocketDisconnect:
        return
    token = bytes(fields["token"]).rstrip(b"\0").decode("ascii", "replace")
    peer = websocket.client
    try:
        client = decision.join(f"ws {peer.host}:{peer.port}" if peer else "ws", token or None)
    except TelerobotError as exc:  # the server is full
        await websocket.send_bytes(error(0, exc.code, str(exc)))
        await websocket.close(code=1013, reason=str(exc)[:120])
        return
    conn = Connection(
        websocket.send_bytes,
        client.id,
        operator=client.role.value == "operator",
        every_force_sample=bool(int(fields["flags"]) & m.HelloFlags.EVERY_FORCE_SAMPLE),
    )
    conn.reply(
        m.encode(m.WELCOME, m.PROTOCOL_VERSION, int(conn.operator), hub.clock.now(), text=client.id)
    )
    hub.add(conn)
    bucket, garbage = TokenBucket(), MalformedRun()
    try:
        while not conn.closed:
            frame = await websocket.receive()
            if frame["type"] == "websocket.disconnect":
                break
            wait = bucket.take(hub.clock.now())
            if wait > 0:  # over its rate: read nothing more until it is back within it
                await hub.clock.sleep(wait)
            data = frame.get("bytes")
            if data is None:
                conn.reply(error(0, "malformed", "binary messages only (see docs/protocol.md)"))
                ok = False
            else:
                received = hub.clock.now()
                decision.seen(client.id)
                ok = await handle(data, received, client.id, conn, decision, hub)
            if garbage.note(not ok):
                reason = f"{garbage.limit} malformed messages in a row: closing"
                await conn.close()  # its sender first: one writer on the socket
                await websocket.send_bytes(error(0, "malformed", reason))
                await websocket.close(code=1008, reason=reason)
                break
    except WebSocketDisconnect:
        pass
    finally:
        await hub.remove(conn)
        await decision.leave(client.id)


def acknowledge(conn: Connection, hub: RealtimeHub, applied: Applied, received: float) -> None:
    result = m.Ack.LIMITED if applied.limited else m.Ack.APPLIED
    conn.reply(m.encode(m.ACK, applied.seq, result, applied.applied_at))
    hub.command_processing.record((applied.applied_at - received) * 1000.0)


async def handle(
    data: bytes,
    received: float,
    client_id: str,
    conn: Connection,
    decision: DecisionServer,
    hub: RealtimeHub,
) -> bool:
    """Decode and carry out one client message; False if it was malformed (an ERROR
    has been queued for the client either way something went wrong)."""
    seq = 0
    try:
        msg, f, _ = m.decode(data)
        seq = int(f.get("seq", 0))
        if msg is m.CART_INC:
            frame = FRAMES.get(int(f["frame"]))
            if frame is None:
                raise m.MalformedMessage(f"unknown frame {f['frame']}", "invalid_command", seq)
            applied = await decision.cartesian_increment(
                client_id,
                np.array([f["dx"], f["dy"], f["dz"]], dtype=float),
                np.array([f["rx"], f["ry"], f["rz"]], dtype=float),
                frame=frame,
                seq=seq,
                client_time=float(f["client_time"]),
            )
            acknowledge(conn, hub, applied, received)
        elif msg is m.JOINT_INC:
            dq = np.array([f[f"dq{i}"] for i in range(1, 7)], dtype=float)
            applied = await decision.joint_increment(
                client_id, dq, seq=seq, client_time=float(f["client_time"])
            )
            acknowledge(conn, hub, applied, received)
        elif msg is m.HEARTBEAT:
            pass  # `seen` above is the heartbeat
        elif msg is m.ESTOP:
            await decision.estop(client_id)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now()))
        elif msg is m.RESET:
            await decision.reset(client_id)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now()))
        elif msg is m.PING:
            conn.reply(m.encode(m.PONG, seq, f["t0"], received, hub.clock.now()))
        elif msg is m.LEASE:
            action = int(f["action"])
            if action == m.LeaseAction.RELEASE:
                await decision.release_lease(client_id)
            elif action in (m.LeaseAction.TAKE, m.LeaseAction.TAKE_OVER):
                await decision.take_lease(client_id, force=action == m.LeaseAction.TAKE_OVER)
            else:
                raise m.MalformedMessage(f"unknown lease action {action}", "invalid_command", seq)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now()))
        else:
            raise m.MalformedMessage(f"{msg.name} is not a client message", "unknown_type", seq)
    except m.MalformedMessage as exc:
        conn.reply(error(exc.seq or seq, exc.code, str(exc)))
        return False
    except TelerobotError as exc:
        conn.reply(error(seq, exc.code, str(exc)))
    return True
