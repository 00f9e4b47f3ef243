"""The DecisionServer (thesis §4.3.3): holds the robot and the force sensor
and applies every command, from any input or the REST API, through one path:

    authorise (client, role, lease, e-stop) → validate → scale → step limit →
    speed limit → frame → force guard → workspace → IK → joint-step limit → driver

Every command ends as one absolute joint target that has passed every check; only
then does it reach the driver. Pure logic: no sockets, no HTTP; time comes from the
injected clock.

Safety owns its loop (docs/architecture.md, rule 15): ``start()`` subscribes to the force
sensor itself and runs the dead-man watchdog (``tick()`` every ``tick_s``) as its own
task (``safety_loop.py``), so the force limit and the dead-man act whatever transports
(``/ws``, the priority channel, REST) are running, or none.

Here: who may command (clients, lease, e-stop, a policy's supervision) and the way to
the driver. Beside it: a command's geometry on one arm (``motion.py``: scale, steps,
speeds, frame, force guard, workspace, IK), the arms by name and index
(``arm_guard.py``, ``Arms``), who may take the lease (``lease.py``) and what is said of
each command (``reports.py``).
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Unpack

import numpy as np

from telerobot.drivers.base import (
    FloatArray,
    ForceSample,
    InvalidCommand,
    NotReady,
    RobotStatus,
    TelerobotError,
    WorkingFrame,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event
from telerobot.protocol.names import client_name
from telerobot.server.control import motion
from telerobot.server.control.arm_guard import ArmGuard, Arms, Felt
from telerobot.server.control.autonomy import Autonomy, AutonomyState, Supervision
from telerobot.server.control.clients import MAX_CLIENTS, Client, ClientTable, Joining, Role
from telerobot.server.control.errors import NotAllowed, SafetyStop
from telerobot.server.control.freshness import CommandAges
from telerobot.server.control.lease import Lease
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.control.policy_tokens import PolicyTokens
from telerobot.server.control.reports import Applied as Applied
from telerobot.server.control.reports import CommandReport as CommandReport
from telerobot.server.control.reports import reported
from telerobot.server.control.safety_loop import SafetyLoop
from telerobot.server.control.slave_port import SlavePort

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SafetyState:
    estop: bool
    estop_reason: str
    force_limited: bool
    lease_holder: str | None
    lease_holder_name: str | None
    # The dead-man stopped the holder's arm; the lease is kept for lease_grace_s.
    halted: bool = False
    lease_note: str = ""  # why control last changed hands (or was lost)
    # The arms stopped by their own force limit (force_limited: any of them is).
    force_limited_arms: tuple[str, ...] = ()


@dataclass
class DecisionEvents:
    lease_changed: Event[str | None] = field(default_factory=lambda: Event("lease_changed"))
    safety_changed: Event[SafetyState] = field(default_factory=lambda: Event("safety_changed"))
    applied: Event[Applied] = field(default_factory=lambda: Event("applied"))
    command: Event[CommandReport] = field(default_factory=lambda: Event("command"))
    autonomy_changed: Event[AutonomyState] = field(
        default_factory=lambda: Event("autonomy_changed")
    )


class DecisionServer:
    def __init__(
        self,
        arms: Sequence[ArmGuard],
        *,
        clock: Clock,
        operator_token: str,
        limits: SafetyLimits | None = None,
        max_clients: int = MAX_CLIENTS,
        policy_tokens: PolicyTokens | None = None,
    ) -> None:
        """``arms``, in order (docs/arms.md): each with its own driver, model, limits and
        force sensor; numbered 1…N on the wire by their place here. ``limits`` holds the
        server's own: the dead-man, the lease's grace, the age of a command."""
        self.arms = Arms(arms)
        self.clock = clock
        self.limits = limits or SafetyLimits()
        self.events = DecisionEvents()
        self.clients = ClientTable(clock, operator_token, policy_tokens, max_clients)
        self.lease = Lease(self.clients, clock, self.limits)
        self._scale = 1.0
        self.frame = WorkingFrame.BASE
        self._estop = False
        self._estop_reason = ""
        self.ages = CommandAges(clock, self.limits)
        self.resumed_sessions = 0  # sessions continued on a new connection
        self._safety_loop = SafetyLoop(self.arms, clock, self.limits, self.on_force, self.tick)
        self.autonomy = Autonomy(clock.now())
        self.supervision = Supervision(
            self.autonomy,
            self.clients,
            self.lease,
            clock,
            changed=self.events.autonomy_changed,
            stop_all=self._stop_all,
            lease_changed=self._changed_lease,
            estopped=lambda: self._estop,
        )

    # ------------------------------------------------------------ its own loop
    def start(self) -> None:
        """Subscribe to the force sensors and start the dead-man watchdog, on the
        running event loop (``SafetyLoop``)."""
        self._safety_loop.start()

    async def stop(self) -> None:
        for guard in self.arms:
            guard.close()  # its solver's thread
        await self._safety_loop.stop()

    # ------------------------------------------------------------ settings
    @property
    def scale(self) -> float:
        """Master-to-slave motion scale applied to Cartesian increments."""
        return self._scale

    @scale.setter
    def scale(self, value: float) -> None:
        if not (isinstance(value, int | float) and math.isfinite(value) and 0.01 <= value <= 10.0):
            raise InvalidCommand(f"scale must be between 0.01 and 10, got {value!r}")
        self._scale = float(value)

    # ------------------------------------------------------------ arms
    @property
    def arm_names(self) -> list[str]:
        return self.arms.names

    def arm(self, name: str | None = None) -> ArmGuard:
        """The arm called ``name``; None: the only arm (``Arms.named``)."""
        return self.arms.named(name)

    def arm_at(self, index: int) -> ArmGuard:
        """The arm by its index on the wire: 1…N, or 0 for the only one."""
        return self.arms.at(index)

    async def _stop_all(self) -> None:
        """Every arm stopped (the e-stop, the dead-man, a lease lost or changing hands)."""
        for guard in self.arms:
            await guard.robot.stop()

    def state(self) -> SafetyState:
        holder = self.clients.known(self.lease.holder)
        limited = tuple(guard.name for guard in self.arms if guard.force_limited)
        return SafetyState(
            self._estop,
            self._estop_reason,
            bool(limited),
            self.lease.holder,
            holder.name if holder else None,
            halted=self.lease.halted,
            lease_note=self.lease.note,
            force_limited_arms=limited,
        )

    # ------------------------------------------------------------ clients
    def join(self, name: str, token: str | None, **how: Unpack[Joining]) -> Client:
        """A new client (``ClientTable.add``, ``Joining``); a policy joining is a stop
        event: it waits for a person's go."""
        client = self.clients.add(name, token, keep=self.lease.holder, **how)
        if client.policy:
            self.autonomy.stopped()
        return client

    async def revoke_policy_token(self, ident: str) -> list[str]:
        """The token revoked and every client that joined with it gone (its lease lapses):
        the ids of those clients (their connections are closed by the caller)."""
        self.clients.policy_tokens.revoke(ident)
        gone = self.clients.joined_with(ident)
        for client_id in gone:
            await self.leave(client_id)
        return gone

    def resume(self, key: str) -> Client:
        """The client whose resume key this is, now on a new connection (its generation
        moves on: the old connection's session is superseded). Heard now: a lease kept
        through the dead-man's grace stays, with the arm halted until a fresh command."""
        found = self.clients.resumable(key)
        self.resumed_sessions += 1
        self._heard(found)
        log.info("%s resumed its session on a new connection", found.name)
        return found

    async def leave(self, client_id: str) -> None:
        self.supervision.left(client_id)
        if self.lease.holder == client_id:
            await self._lapse("controller disconnected")
        self.clients.remove(client_id)

    def rename(self, client_id: str, name: str) -> None:
        """The name ``client_id`` goes by from now on (a NAME message: a client with no
        URL to name itself in, such as the master bridge on the priority channel). A
        name against the rule (telerobot/protocol/names.py) is refused and the old one
        kept; a holder's new name is said at once (the SAFETY event, ``/safety``)."""
        client = self.clients.get(client_id)
        client.name = client_name(name)
        if self.lease.holder == client_id:
            self.events.safety_changed.emit(self.state())

    def seen(self, client_id: str) -> None:
        """A heartbeat: any message from a client counts as one."""
        self._heard(self.clients.get(client_id))

    def heard_beat(self, client_id: str, client_time: float) -> None:
        """A HEARTBEAT on the realtime channels: its transit is the link's (the lease's
        grace follows it, lease.py); ``seen`` counted it already."""
        client = self.clients.known(client_id)
        if client is not None and math.isfinite(client_time):
            self.ages.note_transit(client, client_time)

    def heartbeat(self, client_id: str) -> None:
        """A script's sign of life (``POST /lease/heartbeat``). It keeps the lease its
        client holds; and a client whose task holds the lease in its place (it
        supervises that task) stays present by it, so a script's keep-alive goes on
        while its task runs: its presence, not the lease, is what the task's guard
        checks. Anyone else is told the lease is not theirs."""
        client = self.clients.get(client_id)
        self._heard(client)
        if self.lease.holder == client_id or self.supervises_holder(client_id):
            return
        raise NotAllowed("you do not hold the lease (it may have lapsed: take it again)")

    def supervises_holder(self, client_id: str) -> bool:
        """Whether the lease is held by a task running for ``client_id``."""
        holder = self.clients.known(self.lease.holder)
        return holder is not None and holder.on_behalf_of == client_id

    def _heard(self, client: Client) -> None:
        if self.lease.heard(client):
            self.events.safety_changed.emit(self.state())

    @property
    def lease_holder(self) -> str | None:
        return self.lease.holder

    @property
    def deadman_halts(self) -> int:
        """Arms stopped by the dead-man with the lease kept (GET /safety)."""
        return self.lease.halts

    @reported("lease", action="take")
    async def take_lease(self, client_id: str, *, force: bool = False) -> None:
        client = self.clients.get(client_id)
        client.last_seen = self.clock.now()
        if client.role is Role.OBSERVER:
            raise NotAllowed("observers cannot take control: connect with the operator token")
        if self.lease.holder == client_id:
            return
        if self.lease.holder is not None:
            holder = self.clients.get(self.lease.holder)
            note = self.lease.takeover(
                client, holder, force=force, policy_id=self.autonomy.policy_id
            )
            log.warning("%s takes control from %s", client.name, holder.name)
            await self._stop_all()
        else:
            note = f"taken by {client.name!r}"
        taken_from = self.clients.known(self.lease.holder)
        self.lease.give(client, note)
        self._changed_lease()
        self.supervision.taken(client, taken_from)

    @reported("lease", action="release")
    async def release_lease(self, client_id: str) -> None:
        if self.lease.holder != client_id:
            raise NotAllowed("you do not hold the lease")
        if not await self.supervision.released(self.clients.get(client_id)):
            await self._lapse("released")

    # ------------------------------------------------------------ supervised autonomy
    def _supervisor(self, client_id: str) -> Client:
        """An operator (a person's client, not the policy) acting on the autonomy."""
        client = self.clients.get(client_id)
        self._heard(client)
        self.supervision.check_supervisor(client)
        return client

    @reported("autonomy", action="pause")
    async def pause(self, client_id: str) -> None:
        """Hold the policy still (``Supervision.pause``)."""
        await self.supervision.pause(self._supervisor(client_id))

    @reported("autonomy", action="resume")
    async def resume_policy(self, client_id: str) -> None:
        """The policy drives again (``Supervision.resume``); refused while the e-stop is
        latched."""
        client = self._supervisor(client_id)
        if self._estop:
            raise SafetyStop(f"e-stop is latched ({self._estop_reason}): reset it first")
        await self.supervision.resume(client)

    async def _lapse(self, why: str) -> None:
        if await self.supervision.lapsing(why):
            return
        log.info("lease lapses: %s", why)
        self.lease.drop(why)
        await self._stop_all()
        self._changed_lease()

    def _changed_lease(self) -> None:
        self.events.lease_changed.emit(self.lease.holder)
        self.events.safety_changed.emit(self.state())

    async def tick(self) -> None:
        """The dead-man's check (``Lease.judge``), every ``tick_s``: a silent holder's
        arms stopped, or the lease taken from it."""
        verdict = self.lease.judge()
        if verdict is None:
            return
        if verdict.lapse:
            await self._lapse(verdict.why)
            return
        await self._stop_all()
        self.events.safety_changed.emit(self.state())

    # ------------------------------------------------------------ safety
    @reported("estop")
    async def estop(
        self, client_id: str | None, reason: str = "e-stop pressed", *, source: str = "server"
    ) -> None:
        """Anyone may stop the arm; it stays stopped until an operator resets it."""
        known = self.clients.known(client_id)
        who = known.name if known is not None else "server"
        self._estop, self._estop_reason = True, f"{reason} ({who})"
        self.autonomy.stopped()
        await self._stop_all()
        self.events.safety_changed.emit(self.state())
        self.supervision.paused_by_stop(f"e-stop: {self._estop_reason}")

    @reported("reset")
    async def reset(self, client_id: str) -> None:
        client = self.clients.get(client_id)
        if client.role is not Role.OPERATOR:
            raise NotAllowed("only a person can reset the e-stop (the operator token)")
        supervising = self.lease.holder == self.autonomy.policy_id and not client.policy
        if self.lease.holder not in (None, client_id) and not supervising:
            raise NotAllowed("only the client in control can reset the e-stop")
        self._estop, self._estop_reason = False, ""
        self.events.safety_changed.emit(self.state())

    def master_energy(
        self, client_id: str, e_in: float, e_out: float, *, arm: str | None = None
    ) -> tuple[float, float]:
        """A master arm's books (``ENERGY``: what its operator put into the link and
        got back, J, cumulative); answers the arm's (``PORT_ENERGY``: what the arm's
        surroundings gave back into the link, and what the arm put into them). From
        the first, this client's increments keep to the master's energy
        (``telerobot.server.control.slave_port``)."""
        client = self.clients.get(client_id)
        if client.role is not Role.OPERATOR:
            raise NotAllowed("only an operator's master arm sends its energy")
        if not (math.isfinite(e_in) and math.isfinite(e_out) and e_in >= 0 and e_out >= 0):
            raise InvalidCommand("energies must be finite numbers ≥ 0 (J)")
        guard = self.arm(arm)
        port = client.ports.get(guard.name)
        if port is None:
            port = client.ports[guard.name] = SlavePort()
        port.master_energy(e_in, e_out)
        return port.given, port.out

    def on_force(self, sample: ForceSample, guard: ArmGuard) -> None:
        """Force limit (per arm: ``guard``'s sensor): a contact force above the
        arm's limit stops that arm; only commands that back it away from the contact are
        taken until the force falls below the release level. Any contact (above
        ``contact_force_n``) is remembered: approaching it again is slowed to
        ``contact_speed_m_s`` for ``contact_memory_s``."""
        lim = guard.limits
        fx, fy, fz = sample.values[:3]
        magnitude = math.sqrt(fx * fx + fy * fy + fz * fz)  # 1 kHz: plain floats, no numpy
        holder = self.clients.known(self.lease.holder)
        port = holder.ports.get(guard.name) if holder is not None and holder.ports else None
        if port is not None:
            # Its books are kept on the measured tool (one FK a sample, for a master only).
            pose = guard.robot.pose
            port.add_sample(pose.rotation @ np.array([fx, fy, fz]), pose.position)
        felt = guard.felt(fx, fy, fz, magnitude, self.clock.now())
        if felt is Felt.LIMITED:
            self.autonomy.stopped()
            log.warning(
                "%s",
                guard.said(f"force limit: {magnitude:.1f} N > {lim.force_limit_n:.1f} N, stopping"),
            )
            asyncio.get_running_loop().create_task(guard.robot.stop())
            self.events.safety_changed.emit(self.state())
            self.supervision.paused_by_stop(guard.said(f"force limit: {magnitude:.1f} N"))
        elif felt is Felt.RELEASED:
            self.events.safety_changed.emit(self.state())

    def _authorise(self, client_id: str) -> Client:
        client = self.clients.get(client_id)
        self._heard(client)
        if client.role is Role.OBSERVER:
            raise NotAllowed("observers cannot move the robot")
        self.supervision.check(client)
        if self.lease.holder != client_id:
            raise NotAllowed("take the control lease before moving the robot")
        if self._estop:
            raise SafetyStop(f"e-stop is latched ({self._estop_reason}): reset it first")
        return client

    # ------------------------------------------------------------ commands
    # Each: who may (_authorise), the arm, its age, then its geometry on that arm
    # (motion.py), then _apply. Every refusal is reported (``reported``).
    @reported("cartesian_increment")
    async def cartesian_increment(
        self,
        client_id: str,
        dX: FloatArray,
        rotvec: FloatArray,
        *,
        frame: WorkingFrame | None = None,
        seq: int = 0,
        client_time: float | None = None,
        arm: str | None = None,
    ) -> Applied:
        """ΔX (m) and ΔM as a rotation vector (rad), in ``frame`` (default: the working
        frame), for ``arm`` (None: the only arm)."""
        client = self._authorise(client_id)
        guard = self.arm(arm)
        client.streaming = True
        self.ages.check_fresh(client, client_time)
        dX, rv, step, angle = motion.scaled_increment(guard, dX, rotvec, self._scale)
        now = self.clock.now()
        dt = motion.interval(client.last_command_at.get(guard.name), now)
        frame = frame or self.frame
        # A master arm's port (it sends ENERGY): what the arm still owes its motion
        # comes with this increment, and the part into a contact keeps to its energy.
        port = client.ports.get(guard.name) if frame is WorkingFrame.BASE else None
        wanted = dX
        if port is not None:
            port.settle()
            wanted = dX = dX + port.owed_for(now)
            step = float(np.linalg.norm(dX))
        try:
            q, seed, dX, factor = motion.cartesian_target(
                guard, dX, rv, step, angle, frame=frame, dt=dt, now=now, port=port
            )
            applied = await self._apply(client, guard, q, seed, seq, client_time, factor)
        except TelerobotError:
            if port is not None:  # refused (force limit, workspace…): nothing more is owed
                port.forgive()
            raise
        if port is not None:
            port.moved(dX, wanted)
        return applied

    @reported("joint_increment")
    async def joint_increment(
        self,
        client_id: str,
        dq: FloatArray,
        *,
        seq: int = 0,
        client_time: float | None = None,
        arm: str | None = None,
    ) -> Applied:
        client = self._authorise(client_id)
        guard = self.arm(arm)
        client.streaming = True
        self.ages.check_fresh(client, client_time)
        dt = motion.interval(client.last_command_at.get(guard.name), self.clock.now())
        q, seed, factor = motion.joint_step_target(guard, dq, dt)
        return await self._apply(client, guard, q, seed, seq, client_time, factor)

    @reported("move_joints")
    async def move_joints(
        self, client_id: str, q: FloatArray, *, seq: int = 0, arm: str | None = None
    ) -> Applied:
        """An absolute joint move (scripted): joint limits and the workspace apply; the
        arm's own velocity limits pace it."""
        client = self._authorise(client_id)
        guard = self.arm(arm)
        client.streaming = False  # a bounded move, not jogging: a scripted lease may idle
        q = motion.joints_target(guard, q)
        return await self._apply(client, guard, q, None, seq, None, 1.0)

    @reported("move_pose")
    async def move_pose(
        self,
        client_id: str,
        position: FloatArray,
        rotation: FloatArray,
        *,
        seq: int = 0,
        arm: str | None = None,
    ) -> Applied:
        client = self._authorise(client_id)
        guard = self.arm(arm)
        client.streaming = False
        T = motion.pose_target(guard, position, rotation)
        # Off the event loop (the SO-101's numeric IK takes milliseconds); whatever
        # happened meanwhile (an e-stop, control changing hands) is checked again in
        # _apply before anything moves.
        q = await guard.off_loop(lambda model: model.ik(T, guard.robot.target_joints))
        return await self._apply(client, guard, q, None, seq, None, 1.0)

    @reported("initialize")
    async def initialize(
        self, client_id: str, q: FloatArray | None = None, *, arm: str | None = None
    ) -> None:
        """Connect if needed and initialise (to ``q`` or the home pose); needs the lease."""
        self._authorise(client_id)
        guard = self.arm(arm)
        if q is not None:
            q = motion.joints_target(guard, q, force_stop=False)
        await guard.robot.connect()
        await guard.robot.initialize(q)

    async def _apply(
        self,
        client: Client,
        guard: ArmGuard,
        q: FloatArray,
        seed: FloatArray | None,
        seq: int,
        client_time: float | None,
        scale: float,
    ) -> Applied:
        if seed is not None:
            motion.check_joint_jump(guard, q, seed)
        robot = guard.robot
        async with guard.lock:
            self._still_authorised(client)
            if robot.status not in (RobotStatus.READY, RobotStatus.MOVING):
                raise NotReady(
                    guard.said(f"robot is {robot.status}: initialise it first")
                    + (f" ({robot.status_message})" if robot.status is RobotStatus.ERROR else "")
                )
            # Again as it goes to the driver: the IK and a wait for the lock (another
            # command's move in flight) came after the first check. bench.wan saw one
            # command taken 250.2 ms old. Nothing may come between this check and the
            # driver's call (no await): the age it measures is the command's age at
            # execution (Applied.age). applied_at, taken after the call, is later by
            # the driver's own time.
            age = self.ages.check_age(client, client_time, self.clock.now())
            target = await robot.move_joints(q, relative=False)
            now = self.clock.now()
        client.last_command_at[guard.name] = now
        applied = Applied(
            client.id, seq, client_time, now, scale < 1.0, target, scale, guard.name, age=age
        )
        if age is not None:
            self.ages.executed(client, age)
        self.events.applied.emit(applied)
        return applied

    def _still_authorised(self, client: Client) -> None:
        """As a command goes to the driver after an await (the solver's thread, another
        command's move holding the arm's lock): an e-stop, control changing hands or a
        policy paused meanwhile stops it here, before anything moves."""
        if self.lease.holder != client.id:
            raise NotAllowed("control changed hands while this command waited: not applied")
        if self._estop:
            raise SafetyStop(f"e-stop is latched ({self._estop_reason}): reset it first")
        if client.policy and not self.autonomy.may_drive:
            raise self.autonomy.refuse()
