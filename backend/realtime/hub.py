"""Fan-out of state, forces and events to every WebSocket connection.

Each connection has its own outbox with newest-wins slots (docs/architecture.md, rule 6):
the robot state is one slot (a slow client never receives stale states), force
samples a bounded buffer (every sample is delivered unless a client falls 2 s
behind, which is counted as loss), control replies a small queue. One sender task
per connection drains it in priority order: replies, forces, then state.

A connection replaced by a session's resume (``supersede``) is closed at once, by its
framing (``close_transport``): a client resuming in a loop must not pile up sockets.
Until its framing has let it go it still counts (``open_connections``) against the
client cap, and resumes are limited per address (``resume_limits``).

Force samples come from the sensor's thread through ``call_soon_threadsafe``; for
browsers they are batched (~10 ms), for clients that asked, sent one by one.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import logging
from collections import deque
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from telerobot.drivers.base import ForceSample, RobotStatus, StatusChanged
from telerobot.drivers.clock import Clock
from telerobot.protocol import messages as m
from telerobot.protocol.typed import EventMessage, StateMessage
from telerobot.server.control.arm_guard import ArmGuard, arm_sensors
from telerobot.server.control.autonomy import AutonomyState, Mode
from telerobot.server.control.decision import DecisionServer, SafetyState
from telerobot.server.realtime.ratelimit import PeerLimits
from telerobot.server.telemetry.stats import Telemetry

log = logging.getLogger(__name__)

STATUS_INDEX = {s: i for i, s in enumerate(RobotStatus)}
FORCE_BATCH = 10  # samples per FORCE message for batching clients
FORCE_BATCH_S = 0.010  # …or this long after the first buffered sample
FORCE_BUFFER = 2000  # samples a client may fall behind before the oldest are dropped
# Resumes per address: a page on a flaky link resumes once per stall (≥ 400 ms of
# silence, one attempt at a time), so a few a second at most; more is a loop.
RESUMES_PER_S = 2.0
RESUME_BURST = 10


@dataclass
class Outbox:
    replies: deque[bytes] = field(default_factory=lambda: deque(maxlen=1000))
    # (arm index, sample): every arm's in one buffer, sent as a FORCE per arm
    forces: deque[tuple[int, ForceSample]] = field(
        default_factory=lambda: deque(maxlen=FORCE_BUFFER)
    )
    state: bytes | None = None
    states: list[bytes] | None = None  # every arm's, on a server with more than one
    forces_lost: int = 0


class Connection:
    def __init__(
        self,
        send: Callable[[bytes], Awaitable[None]],
        client_id: str,
        *,
        operator: bool,
        every_force_sample: bool,
        direct_forces: bool = False,
        close_transport: Callable[[], Awaitable[None]] | None = None,
    ) -> None:
        self._send = send
        # Closes the socket under it (the framing's): called once it is superseded.
        self.close_transport = close_transport
        # The priority channel writes forces from the sensor's thread itself.
        self.direct_forces = direct_forces
        self.client_id = client_id
        self.operator = operator
        self.every_force_sample = every_force_sample
        self.outbox = Outbox()
        self._ready = asyncio.Event()
        self._flush_timer: asyncio.TimerHandle | None = None
        self._task: asyncio.Task[None] | None = None
        self.closed = False

    def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name=f"ws-sender-{self.client_id}")

    async def close(self) -> None:
        self.closed = True
        if self._flush_timer is not None:
            self._flush_timer.cancel()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task

    def reply(self, data: bytes) -> None:
        self.outbox.replies.append(data)
        self._ready.set()

    def set_state(self, data: bytes) -> None:
        self.outbox.state = data
        self._ready.set()

    def set_states(self, states: list[bytes]) -> None:
        """Every arm's STATE (the newest of each replaces the one not yet sent)."""
        self.outbox.states = states
        self._ready.set()

    def add_force(self, sample: ForceSample, arm: int = 1) -> None:
        if self.direct_forces:
            return
        box = self.outbox
        if len(box.forces) == box.forces.maxlen:
            box.forces_lost += 1
        box.forces.append((arm, sample))
        if self.every_force_sample or len(box.forces) >= FORCE_BATCH:
            self._ready.set()
        elif self._flush_timer is None:
            self._flush_timer = asyncio.get_running_loop().call_later(FORCE_BATCH_S, self._flush)

    def _flush(self) -> None:
        self._flush_timer = None
        self._ready.set()

    async def _run(self) -> None:
        box = self.outbox
        try:
            while True:
                await self._ready.wait()
                self._ready.clear()
                while box.replies:
                    await self._send(box.replies.popleft())
                if box.forces and (
                    self.every_force_sample
                    or len(box.forces) >= FORCE_BATCH
                    or self._flush_timer is None
                ):
                    by_arm: dict[int, list[tuple[int, float, tuple[float, ...]]]] = {}
                    for arm, s in box.forces:
                        by_arm.setdefault(arm, []).append((s.seq, s.time, s.values))
                    box.forces.clear()
                    if self._flush_timer is not None:
                        self._flush_timer.cancel()
                        self._flush_timer = None
                    for arm, batch in by_arm.items():
                        for i in range(0, len(batch), 500):
                            await self._send(m.encode_force(batch[i : i + 500], arm))
                if box.state is not None:
                    state, box.state = box.state, None
                    await self._send(state)
                if box.states is not None:
                    states, box.states = box.states, None
                    for state in states:
                        await self._send(state)
        except asyncio.CancelledError:
            raise
        except Exception as exc:  # the socket went away: the receive loop will notice
            log.info("sender for %s stopped: %s", self.client_id, exc)
            self.closed = True


class RealtimeHub:
    def __init__(
        self,
        decision: DecisionServer,
        telemetry: Telemetry,
        clock: Clock,
        *,
        state_rate_hz: float = 50.0,
    ) -> None:
        self.decision = decision
        self.telemetry = telemetry
        self.clock = clock
        self.state_period = 1.0 / state_rate_hz
        self.connections: dict[str, Connection] = {}
        # Replaced by a resume, their sockets being closed: gone once their framing
        # has let them go (``remove``).
        self.superseded: set[Connection] = set()
        self.superseded_total = 0
        self._closing: set[asyncio.Task[None]] = set()
        self.resume_limits = PeerLimits(
            connections_per_s=RESUMES_PER_S, connection_burst=RESUME_BURST
        )
        self._state_seq = 0
        self._tasks: list[asyncio.Task[None]] = []
        self._unsubscribe: list[Callable[[], None]] = []
        self._force_interarrival = telemetry.interarrival("force_at_server")
        self._state_interarrival = telemetry.interarrival("state_broadcast")
        # Frame received on /ws → command taken by the driver (server side of the latency).
        self.command_processing = telemetry.stats("command_processing")

    # ------------------------------------------------------------ lifecycle
    def start(self) -> None:
        loop = asyncio.get_running_loop()
        for index, sensor in arm_sensors(self.decision.arms):

            def from_sensor_thread(sample: ForceSample, arm: int = index) -> None:
                loop.call_soon_threadsafe(self._on_force, sample, arm)

            self._unsubscribe.append(sensor.subscribe(from_sensor_thread))
        for guard in self.decision.arms:
            self._unsubscribe.append(
                guard.robot.events.status_changed.subscribe(
                    functools.partial(self._on_status, guard=guard)
                )
            )
        self._unsubscribe.append(self.decision.events.safety_changed.subscribe(self._on_safety))
        self._unsubscribe.append(self.decision.events.autonomy_changed.subscribe(self._on_autonomy))
        self._tasks.append(asyncio.create_task(self._broadcast_state(), name="state-broadcast"))

    async def stop(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        for task in self._tasks:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        for task in list(self._closing):
            task.cancel()
        for conn in [*self.connections.values(), *self.superseded]:
            await conn.close()

    @property
    def open_connections(self) -> int:
        """Connections whose sockets are open: in the fan-out, or superseded and closing."""
        return len(self.connections) + len(self.superseded)

    def add(self, conn: Connection) -> None:
        self.connections[conn.client_id] = conn
        conn.start()
        self._send_states(conn)

    def supersede(self, client_id: str) -> None:
        """The client resumed on a new connection: its old one gets nothing more, its
        reader stops at its next message, and its socket is closed now (a stalled
        link's peer may never send that message)."""
        old = self.connections.pop(client_id, None)
        if old is None:
            return
        old.closed = True
        self.superseded.add(old)
        self.superseded_total += 1
        task = asyncio.create_task(self._close_superseded(old), name=f"supersede-{client_id}")
        self._closing.add(task)
        task.add_done_callback(self._closing.discard)

    async def _close_superseded(self, conn: Connection) -> None:
        await conn.close()  # its sender first: one writer on the socket
        if conn.close_transport is None:
            return
        try:
            await conn.close_transport()
        except Exception as exc:  # already closed by its peer or its own reader
            log.debug("superseded connection of %s: %s", conn.client_id, exc)

    async def remove(self, conn: Connection) -> None:
        # A resumed session's new connection has the same client id: leave that one be.
        if self.connections.get(conn.client_id) is conn:
            del self.connections[conn.client_id]
        self.superseded.discard(conn)
        await conn.close()

    # ------------------------------------------------------------ streams
    def _on_force(self, sample: ForceSample, arm: int = 1) -> None:
        if arm == 1:  # the interarrival is the first sensor's (they run on one clock)
            self._force_interarrival.tick(self.clock.now())
        for conn in self.connections.values():
            conn.add_force(sample, arm)

    def broadcast_event(self, kind: m.EventKind, text: str) -> None:
        data = EventMessage(kind=kind, server_time=self.clock.now(), text=text).encode()
        for conn in self.connections.values():
            conn.reply(data)

    def _on_status(self, change: StatusChanged, guard: ArmGuard | None = None) -> None:
        # READY ↔ MOVING flips with every teleoperation command; STATE carries it at
        # 50 Hz. Events are for what a person should read: errors, (re)initialisation.
        # With two arms or more, each says which arm it is about ("right: ERROR: …").
        routine = {change.old, change.new} <= {RobotStatus.READY, RobotStatus.MOVING}
        if not routine:
            text = f"{change.new.value}: {change.message}"
            if guard is not None:
                text = guard.said(text)
            self.broadcast_event(m.EventKind.STATUS, text)

    def _on_autonomy(self, state: AutonomyState) -> None:
        self.broadcast_event(m.EventKind.AUTONOMY, json.dumps(state.as_dict()))

    def autonomy_event(self) -> bytes | None:
        """The supervision as it is now, for a client that just joined (the EVENTs say
        only changes); None with no policy."""
        state = self.decision.autonomy.state()
        if state.mode is Mode.OFF:
            return None
        text = json.dumps(state.as_dict())
        event = EventMessage(kind=m.EventKind.AUTONOMY, server_time=self.clock.now(), text=text)
        return event.encode()

    def _on_safety(self, state: SafetyState) -> None:
        parts = [f"control: {state.lease_holder_name or 'nobody'}"]
        if state.lease_note:
            parts[0] += f" ({state.lease_note})"
        if state.halted:
            parts.append("HALTED: the dead-man stopped the arm; the lease is kept a moment")
        if state.estop:
            parts.append(f"E-STOP: {state.estop_reason}")
        if state.force_limited:
            which = (
                f" ({', '.join(state.force_limited_arms)})" if len(self.decision.arms) > 1 else ""
            )
            parts.append(f"FORCE LIMIT{which}: back away from the contact")
        self.broadcast_event(m.EventKind.SAFETY, "; ".join(parts))

    def encode_state(self, conn: Connection) -> bytes:
        return self.encode_state_for(conn.client_id, conn.operator)

    def encode_states_for(self, client_id: str | None, operator: bool) -> list[bytes]:
        """Every arm's STATE as ``client_id`` sees it."""
        return [self.encode_state_for(client_id, operator, guard) for guard in self.decision.arms]

    def _send_states(self, conn: Connection) -> None:
        if len(self.decision.arms) == 1:
            conn.set_state(self.encode_state(conn))
        else:
            conn.set_states(self.encode_states_for(conn.client_id, conn.operator))

    def encode_state_for(
        self, client_id: str | None, operator: bool, guard: ArmGuard | None = None
    ) -> bytes:
        """STATE of ``guard``'s arm (the first if None) as ``client_id`` sees it (None:
        an observer with no connection here, e.g. one watching through the media
        server)."""
        guard = guard or self.decision.arms[0]
        robot = guard.robot
        q = robot.joints
        pose = robot.pose
        safety = self.decision.state()
        flags = 0
        if client_id is not None and safety.lease_holder == client_id:
            flags |= m.StateFlags.YOU_HAVE_CONTROL
        if safety.lease_holder is not None:
            flags |= m.StateFlags.SOMEONE_HAS_CONTROL
        if safety.estop:
            flags |= m.StateFlags.ESTOP
        if guard.force_limited:
            flags |= m.StateFlags.FORCE_LIMITED
        if safety.halted:
            flags |= m.StateFlags.HALTED
        if operator:
            flags |= m.StateFlags.OPERATOR
        x, y, z = pose.position.tolist()
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = pose.rotation.tolist()
        state = StateMessage(
            seq=self._state_seq,
            server_time=self.clock.now(),
            status=STATUS_INDEX[robot.status],
            flags=flags,
            x=x, y=y, z=z,
            r00=r00, r01=r01, r02=r02,
            r10=r10, r11=r11, r12=r12,
            r20=r20, r21=r21, r22=r22,
            arm=guard.index,
            joints=tuple(q.tolist()),
        )  # fmt: skip
        return state.encode()

    async def _broadcast_state(self) -> None:
        while True:
            await self.clock.sleep(self.state_period)
            self._state_interarrival.tick(self.clock.now())
            self._state_seq += 1
            for conn in list(self.connections.values()):
                self._send_states(conn)
