"""One client of the real-time protocol, whatever carries its bytes (docs/architecture.md,
rule 16): HELLO checked, the client joined to the DecisionServer, its WELCOME, its
place in the hub's fan-out, every later message decoded, checked and carried out,
and its leaving. ``/ws`` (``ws.py``) and the priority channel (``priority.py``) are
framings around it: they move bytes, this decides what they mean.

Anything malformed, unknown, of the wrong size or carrying NaN gets an ERROR back
and nothing moves; the session and the server stay up.
"""

from __future__ import annotations

import secrets
from collections.abc import Awaitable, Callable
from typing import Any

import numpy as np

from telerobot.drivers.base import TelerobotError, WorkingFrame
from telerobot.protocol import messages as m
from telerobot.server.control.clients import RESUME_KEY_BYTES, Client
from telerobot.server.control.decision import Applied, DecisionServer
from telerobot.server.control.errors import NotAllowed
from telerobot.server.realtime.hub import Connection, RealtimeHub

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


class Session:
    """A joined client: open it from its HELLO (``open`` raises ``MalformedMessage``
    or the DecisionServer's ``TelerobotError`` when it cannot join), send ``welcome``
    the way the framing must (first on the wire), ``attach`` it to the fan-out, hand
    it every later message with ``receive``, and ``close`` it once."""

    def __init__(
        self, decision: DecisionServer, hub: RealtimeHub, client: Client, conn: Connection
    ) -> None:
        self.decision = decision
        self.hub = hub
        self.client = client
        self.conn = conn
        self.generation = client.generation
        self._closed = False

    @classmethod
    def open(
        cls,
        hello: bytes,
        *,
        decision: DecisionServer,
        hub: RealtimeHub,
        peer: str,
        send: Callable[[bytes], Awaitable[None]],
        every_force_sample: bool | None = None,
        direct_forces: bool = False,
        source: str = "ws",
        address: str = "",
        close_transport: Callable[[], Awaitable[None]] | None = None,
    ) -> Session:
        """``every_force_sample`` None: as the HELLO's flags ask. ``address``: the
        peer's IP (resumes are limited per address); ``close_transport``: closes this
        connection's socket, called when a resume supersedes it."""
        fields = check_hello(hello)
        token = bytes(fields["token"]).rstrip(b"\0").decode("ascii", "replace")
        flags = int(fields["flags"])
        if hub.open_connections >= decision.clients.max_clients:
            raise NotAllowed(
                f"this server already has {hub.open_connections} connections"
                f" ({len(hub.superseded)} of them closing): try again in a few seconds"
            )
        if flags & m.HelloFlags.RESUME:
            # Before the key is looked at: a loop of guesses pays the same budget.
            if hub.resume_limits.connect(address, hub.clock.now()) is None:
                limits = hub.resume_limits
                raise NotAllowed(
                    f"too many resumes from {address or 'your address'}: at most"
                    f" {limits.connection_burst:g} at once, then {limits.connections_per_s:g}"
                    " a second; wait a few seconds or connect afresh"
                )
            client = decision.resume(token)
            hub.supersede(client.id)  # the stalled connection gets nothing more, and closes
            # A key resumes once: the new one goes out in this connection's WELCOME (a
            # key seen on the way is worth nothing once its owner has used it).
            client.resume_key = (
                secrets.token_urlsafe(RESUME_KEY_BYTES) if flags & m.HelloFlags.RESUMABLE else None
            )
        else:
            client = decision.join(
                peer,
                token or None,
                source=source,
                synced_clock=bool(flags & m.HelloFlags.SYNCED_CLOCK),
                resumable=bool(flags & m.HelloFlags.RESUMABLE),
                policy=bool(flags & m.HelloFlags.POLICY),
            )
        if every_force_sample is None:
            every_force_sample = bool(flags & m.HelloFlags.EVERY_FORCE_SAMPLE)
        conn = Connection(
            send,
            client.id,
            operator=client.role.value != "observer",  # may drive: a person or a policy
            every_force_sample=every_force_sample,
            direct_forces=direct_forces,
            close_transport=close_transport,
        )
        return cls(decision, hub, client, conn)

    @property
    def id(self) -> str:
        return self.client.id

    @property
    def superseded(self) -> bool:
        """Its client resumed on another connection: this one only closes."""
        return self.client.generation != self.generation

    @property
    def welcome(self) -> list[bytes]:
        """WELCOME, then an ARM for each arm (first on the wire, in this order)."""
        key = self.client.resume_key
        arms = self.decision.arms
        return [
            m.encode(
                m.WELCOME,
                m.PROTOCOL_VERSION,
                int(self.conn.operator),
                self.hub.clock.now(),
                arms[0].dof,
                len(arms),
                text=self.client.id if key is None else f"{self.client.id} {key}",
            ),
            *(m.encode(m.ARM, guard.index, guard.dof, text=guard.name) for guard in arms),
        ]

    def attach(self) -> None:
        """From now on the client gets states, forces and events (a policy's
        supervision first, if one is connected: the events say only its changes)."""
        self.hub.add(self.conn)
        autonomy = self.hub.autonomy_event()
        if autonomy is not None:
            self.conn.reply(autonomy)

    async def receive(self, data: bytes, received: float) -> bool:
        """One message from the client (any message but PING is a heartbeat); False if
        it was malformed. A PING is the transport's clock sync, which the page's worker
        sends on its own every 2 s: it says nothing of the operator being there. A
        superseded session's messages (a stalled link's backlog) are dropped unread."""
        if self.superseded:
            return True
        if data[:1] != bytes((m.PING.type_id,)):
            self.decision.seen(self.client.id)
        return await handle(data, received, self.client.id, self.conn, self.decision, self.hub)

    async def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        await self.hub.remove(self.conn)
        if not self.superseded:
            await self.decision.leave(self.client.id)


def acknowledge(conn: Connection, hub: RealtimeHub, applied: Applied, received: float) -> None:
    result = m.Ack.LIMITED if applied.limited else m.Ack.APPLIED
    conn.reply(m.encode(m.ACK, applied.seq, result, applied.applied_at, applied.scale))
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
        msg, f, text = m.decode(data)
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
                arm=decision.arm_at(int(f["arm"])).name,
            )
            acknowledge(conn, hub, applied, received)
        elif msg is m.JOINT_INC:
            dq = np.array(f["joints"], dtype=float)  # the DecisionServer checks the count
            applied = await decision.joint_increment(
                client_id,
                dq,
                seq=seq,
                client_time=float(f["client_time"]),
                arm=decision.arm_at(int(f["arm"])).name,
            )
            acknowledge(conn, hub, applied, received)
        elif msg is m.HEARTBEAT:
            pass  # `seen` above is the heartbeat
        elif msg is m.ESTOP:
            await decision.estop(client_id)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now(), 1.0))
        elif msg is m.RESET:
            await decision.reset(client_id)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now(), 1.0))
        elif msg is m.PING:
            conn.reply(m.encode(m.PONG, seq, f["t0"], received, hub.clock.now()))
        elif msg is m.LEASE:
            action = int(f["action"])
            if action == m.LeaseAction.RELEASE:
                await decision.release_lease(client_id)
            elif action in (m.LeaseAction.TAKE, m.LeaseAction.TAKE_OVER):
                await decision.take_lease(client_id, force=action == m.LeaseAction.TAKE_OVER)
            elif action == m.LeaseAction.PAUSE:
                await decision.pause(client_id)
            elif action == m.LeaseAction.RESUME:
                await decision.resume_policy(client_id)
            else:
                raise m.MalformedMessage(f"unknown lease action {action}", "invalid_command", seq)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now(), 1.0))
        elif msg is m.ENERGY:
            given, out = decision.master_energy(
                client_id,
                float(f["e_in"]),
                float(f["e_out"]),
                arm=decision.arm_at(int(f["arm"])).name,
            )
            conn.reply(m.encode(m.PORT_ENERGY, seq, given, out))
        elif msg is m.NAME:
            decision.rename(client_id, text)
            conn.reply(m.encode(m.ACK, seq, m.Ack.APPLIED, hub.clock.now(), 1.0))
        elif msg is m.DATAGRAMS:
            raise m.MalformedMessage(
                "DATAGRAMS is for the priority channel (forces over UDP), not this one",
                "invalid_command",
                seq,
            )
        else:
            raise m.MalformedMessage(f"{msg.name} is not a client message", "unknown_type", seq)
    except m.MalformedMessage as exc:
        conn.reply(error(exc.seq or seq, exc.code, str(exc)))
        return False
    except TelerobotError as exc:
        conn.reply(error(seq, exc.code, str(exc)))
    return True
