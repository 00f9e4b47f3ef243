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
from typing import assert_never

import numpy as np

from telerobot.drivers.base import TelerobotError, WorkingFrame
from telerobot.protocol import messages as m
from telerobot.protocol.typed import (
    AckMessage,
    AnyMessage,
    ArmMessage,
    CartIncMessage,
    DatagramsMessage,
    EnergyMessage,
    ErrorMessage,
    EstopMessage,
    EventMessage,
    ForceMessage,
    HeartbeatMessage,
    HelloMessage,
    JointIncMessage,
    LeaseMessage,
    NameMessage,
    PingMessage,
    PongMessage,
    PortEnergyMessage,
    ResetMessage,
    StateMessage,
    WelcomeMessage,
    parse,
    seq_of,
)
from telerobot.server.control.clients import RESUME_KEY_BYTES, Client
from telerobot.server.control.decision import Applied, DecisionServer
from telerobot.server.control.errors import NotAllowed
from telerobot.server.realtime.hub import Connection, RealtimeHub

FRAMES: dict[int, WorkingFrame] = {
    m.Frame.BASE: WorkingFrame.BASE,
    m.Frame.WRIST: WorkingFrame.WRIST,
    m.Frame.TOOL: WorkingFrame.TOOL,
}


def check_hello(data: bytes) -> HelloMessage:
    """The first message, if it is a HELLO this server speaks."""
    hello = parse(data)
    if not isinstance(hello, HelloMessage):
        raise m.MalformedMessage(f"the first message must be HELLO, got {hello.SPEC.name}")
    if hello.version != m.PROTOCOL_VERSION:
        raise m.MalformedMessage(
            f"protocol version {hello.version} is not spoken here: this server speaks"
            f" {m.PROTOCOL_VERSION} (update the client)"
        )
    return hello


def error(seq: int, code: str, text: str) -> bytes:
    code_number = m.ERROR_CODES.get(code, m.ERROR_CODES["telerobot_error"])
    return ErrorMessage(seq=seq, code=code_number, text=text).encode()


def applied_now(seq: int, hub: RealtimeHub) -> bytes:
    """The ACK of a command carried out at once (nothing scaled it)."""
    return AckMessage(
        seq=seq, result=m.Ack.APPLIED, server_time=hub.clock.now(), scale=1.0
    ).encode()


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
        checked = check_hello(hello)
        token = checked.token.rstrip(b"\0").decode("ascii", "replace")
        flags = checked.flags
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
        welcome = WelcomeMessage(
            version=m.PROTOCOL_VERSION,
            role=int(self.conn.operator),
            server_time=self.hub.clock.now(),
            joints=arms[0].dof,
            arms=len(arms),
            text=self.client.id if key is None else f"{self.client.id} {key}",
        )
        return [
            welcome.encode(),
            *(ArmMessage(index=g.index, joints=g.dof, text=g.name).encode() for g in arms),
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
    ack = AckMessage(
        seq=applied.seq, result=result, server_time=applied.applied_at, scale=applied.scale
    )
    conn.reply(ack.encode())
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
        msg = parse(data)
        seq = seq_of(msg)
        await carry_out(msg, received, client_id, conn, decision, hub)
    except m.MalformedMessage as exc:
        conn.reply(error(exc.seq or seq, exc.code, str(exc)))
        return False
    except TelerobotError as exc:
        conn.reply(error(seq, exc.code, str(exc)))
    return True


async def carry_out(
    msg: AnyMessage,
    received: float,
    client_id: str,
    conn: Connection,
    decision: DecisionServer,
    hub: RealtimeHub,
) -> None:
    """One parsed message: every kind has its case (mypy checks it, ``assert_never``)."""
    match msg:
        case CartIncMessage():
            frame = FRAMES.get(msg.frame)
            if frame is None:
                raise m.MalformedMessage(f"unknown frame {msg.frame}", "invalid_command", msg.seq)
            applied = await decision.cartesian_increment(
                client_id,
                np.array([msg.dx, msg.dy, msg.dz], dtype=float),
                np.array([msg.rx, msg.ry, msg.rz], dtype=float),
                frame=frame,
                seq=msg.seq,
                client_time=msg.client_time,
                arm=decision.arm_at(msg.arm).name,
            )
            acknowledge(conn, hub, applied, received)
        case JointIncMessage():
            applied = await decision.joint_increment(
                client_id,
                np.array(msg.joints, dtype=float),  # the DecisionServer checks the count
                seq=msg.seq,
                client_time=msg.client_time,
                arm=decision.arm_at(msg.arm).name,
            )
            acknowledge(conn, hub, applied, received)
        case HeartbeatMessage():
            # `seen` (Session.receive) is the heartbeat; its transit is the link's
            decision.heard_beat(client_id, msg.client_time)
        case EstopMessage():
            await decision.estop(client_id)
            conn.reply(applied_now(msg.seq, hub))
        case ResetMessage():
            await decision.reset(client_id)
            conn.reply(applied_now(msg.seq, hub))
        case PingMessage():
            pong = PongMessage(seq=msg.seq, t0=msg.t0, t1=received, t2=hub.clock.now())
            conn.reply(pong.encode())
        case LeaseMessage():
            await lease(msg, client_id, decision)
            conn.reply(applied_now(msg.seq, hub))
        case EnergyMessage():
            given, out = decision.master_energy(
                client_id, msg.e_in, msg.e_out, arm=decision.arm_at(msg.arm).name
            )
            conn.reply(PortEnergyMessage(seq=msg.seq, e_in=given, e_out=out).encode())
        case NameMessage():
            decision.rename(client_id, msg.text)
            conn.reply(applied_now(msg.seq, hub))
        case DatagramsMessage():
            raise m.MalformedMessage(
                "DATAGRAMS is for the priority channel (forces over UDP), not this one",
                "invalid_command",
                msg.seq,
            )
        case (
            HelloMessage() | WelcomeMessage() | StateMessage() | ForceMessage() | EventMessage()
            | ErrorMessage() | AckMessage() | PongMessage() | PortEnergyMessage() | ArmMessage()
        ):  # fmt: skip
            # (HELLO only opens a session: a second one is as out of place as these)
            raise m.MalformedMessage(
                f"{msg.SPEC.name} is not a client message", "unknown_type", seq_of(msg)
            )
        case _:
            assert_never(msg)


async def lease(msg: LeaseMessage, client_id: str, decision: DecisionServer) -> None:
    action = msg.action
    if action == m.LeaseAction.RELEASE:
        await decision.release_lease(client_id)
    elif action in (m.LeaseAction.TAKE, m.LeaseAction.TAKE_OVER):
        await decision.take_lease(client_id, force=action == m.LeaseAction.TAKE_OVER)
    elif action == m.LeaseAction.PAUSE:
        await decision.pause(client_id)
    elif action == m.LeaseAction.RESUME:
        await decision.resume_policy(client_id)
    else:
        raise m.MalformedMessage(f"unknown lease action {action}", "invalid_command", msg.seq)
