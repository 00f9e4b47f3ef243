"""Supervised autonomy: a learned policy drives, an operator supervises and takes over
(docs/architecture.md, "Supervised autonomy").

A client that joins as a *policy* (HELLO's ``POLICY`` flag; the LeRobot robot plugin
does) may hold the lease like any operator, and every command of its passes the same
DecisionServer checks. What this adds is who may drive while a policy is connected,
as a state machine with lerobot's DAgger names:

- ``AUTONOMOUS``: the policy holds the lease and its commands are applied.
- ``PAUSED``: the policy keeps the lease but its commands are refused (said to it,
  counted); the arm holds still. Only a person's resume ends it.
- ``CORRECTING``: an operator took the lease from the policy (no ``force`` needed: a
  person always may); the policy's commands are refused. The operator drives from where
  the arm is: taking the lease stops the arm, and every input moves by increments from
  the measured pose (a master or leader aligns first, as it always does).
- Handing back (the operator releases, or ``RESUME``): the lease goes back to the policy,
  ``AUTONOMOUS`` (or ``PAUSED``: ``autonomy_release`` = ``pause``).
- ``OFF``: no policy has held the lease since it joined, or it left.

**The one rule** (``Autonomy.may_drive``): a policy's command moves the arm only if a
person said go (a resume, or a hand-back) after the last *stop event*. Stop events: the
e-stop, a force stop, a pause, any lease lapse, and a policy joining, taking the lease
or leaving. So a policy starts PAUSED (a rollout starts when a person says go), a
restarted or reconnected policy comes back PAUSED, and a hand-back while the e-stop is
latched or an arm is force-stopped leaves it PAUSED ("press P to let it drive"). The
mode is what is shown; the count of stops against the count at the last go is what is
enforced, so no path that forgets to set the mode can let a policy drive.

Every change is an ``AutonomyState`` on ``events.autonomy_changed``, with its cause: the
recording logs them (``/autonomy``), the export's ``intervention`` column comes from
them, the page shows them.
"""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import StrEnum

from telerobot.drivers.base import TelerobotError
from telerobot.drivers.clock import Clock
from telerobot.drivers.events import Event
from telerobot.server.control.clients import Client, ClientTable, Role
from telerobot.server.control.errors import NotAllowed
from telerobot.server.control.lease import Lease

log = logging.getLogger(__name__)


class Mode(StrEnum):
    OFF = "off"
    AUTONOMOUS = "autonomous"
    PAUSED = "paused"
    CORRECTING = "correcting"


class ReleaseTo(StrEnum):
    """Where an operator's release during a correction leaves the policy."""

    AUTONOMOUS = "autonomous"
    PAUSE = "pause"


RATE_SMOOTHING = 0.1  # the policy's command rate: an exponential average of its intervals


class Supervised(TelerobotError):
    """The policy's command was refused: the operator has paused it or is correcting."""

    code = "not_allowed"
    http_status = 409


@dataclass(frozen=True)
class AutonomyState:
    mode: Mode
    policy_id: str | None
    policy: str | None  # its name
    operator: str | None  # who is correcting, paused or resumed it last
    cause: str
    rate_hz: float  # the policy's commands a second, as received
    refused: int  # its commands refused while paused or corrected, this session
    interventions: int  # takeovers this session
    t: float  # when it changed (server clock)

    def as_dict(self) -> dict[str, object]:
        return {
            "mode": self.mode.value,
            "policy": self.policy,
            "operator": self.operator,
            "cause": self.cause,
            "rate_hz": round(self.rate_hz, 1),
            "refused": self.refused,
            "interventions": self.interventions,
        }


class Autonomy:
    """The mode and its counters. ``Supervision`` moves it over the lease; this keeps
    what was decided and says it."""

    def __init__(self, now: float) -> None:
        self.mode = Mode.OFF
        self.policy_id: str | None = None
        self.policy: str | None = None
        self.operator: str | None = None
        self.cause = "no policy"
        self.refused = 0
        self.interventions = 0
        self.changed_at = now
        self._rate_interval: float | None = None
        self._last_command: float | None = None
        # The rule (module doc): stop events so far, and their count at a person's last go.
        self.stops = 0
        self._go_at: int | None = None

    def stopped(self) -> None:
        """A stop event: whatever a person said before no longer lets the policy drive."""
        self.stops += 1

    def go(self) -> None:
        """A person said go (a resume, a hand-back) with nothing stopped."""
        self._go_at = self.stops

    @property
    def may_drive(self) -> bool:
        """Whether the policy's commands are applied: AUTONOMOUS, and a person's go came
        after the last stop event."""
        return self.mode is Mode.AUTONOMOUS and self._go_at == self.stops

    def state(self) -> AutonomyState:
        return AutonomyState(
            self.mode,
            self.policy_id,
            self.policy,
            self.operator,
            self.cause,
            1.0 / self._rate_interval if self._rate_interval else 0.0,
            self.refused,
            self.interventions,
            self.changed_at,
        )

    def set(self, mode: Mode, cause: str, now: float, *, operator: str | None = None) -> bool:
        """Whether anything changed (then the caller says so)."""
        if mode is self.mode and cause == self.cause:
            return False
        if mode is Mode.CORRECTING and self.mode is not Mode.CORRECTING:
            self.interventions += 1
        self.mode, self.cause, self.changed_at = mode, cause, now
        if operator is not None:
            self.operator = operator
        return True

    def start(self, policy_id: str, name: str) -> None:
        if policy_id != self.policy_id:
            self.refused = self.interventions = 0
            self._rate_interval = self._last_command = None
        self.policy_id, self.policy = policy_id, name

    def end(self) -> None:
        self.policy_id = self.policy = self.operator = None

    def heard_command(self, now: float) -> None:
        """A command of the policy's arrived (applied or not): its rate."""
        last, self._last_command = self._last_command, now
        if last is None or now <= last:
            return
        gap = now - last
        avg = self._rate_interval
        self._rate_interval = gap if avg is None else avg + RATE_SMOOTHING * (gap - avg)

    def refuse(self) -> Supervised:
        self.refused += 1
        if self.mode is Mode.CORRECTING:
            why = f"{self.operator or 'an operator'} is correcting"
            then = "you drive again when the operator hands control back"
        else:
            why = f"autonomy is paused ({self.cause})"
            then = "you drive again when a person resumes you (P on the page, /autonomy/resume)"
        return Supervised(
            f"{why}: your command was not applied ({self.refused} refused so far); {then}"
        )


class Supervision:
    """A person's supervision of a policy, over the lease: the mode as control changes
    hands (a policy taking the lease, a person taking over, a hand-back, a lapse, a
    pause or resume) and the hand-back itself. The DecisionServer authorises and
    reports each command, and says when a stop event happens; what it means for the
    policy is decided here."""

    def __init__(
        self,
        autonomy: Autonomy,
        clients: ClientTable,
        lease: Lease,
        clock: Clock,
        *,
        changed: Event[AutonomyState],
        stop_all: Callable[[], Awaitable[None]],
        lease_changed: Callable[[], None],
        estopped: Callable[[], bool],
    ) -> None:
        self.autonomy = autonomy
        self.clients = clients
        self.lease = lease
        self.clock = clock
        self._changed = changed
        self._stop_all = stop_all
        self._lease_changed = lease_changed
        self._estopped = estopped
        self.release_to = ReleaseTo.AUTONOMOUS  # where an operator's release leaves a policy

    def set_mode(self, mode: Mode, cause: str, *, operator: str | None = None) -> None:
        if self.autonomy.set(mode, cause, self.clock.now(), operator=operator):
            log.info("autonomy %s: %s", mode.value.upper(), cause)
            self._changed.emit(self.autonomy.state())

    def paused_by_stop(self, cause: str) -> None:
        """A safety stop (the e-stop, a force stop) pauses a policy that was driving
        (the stop event itself is counted where it happens)."""
        if self.autonomy.mode is Mode.AUTONOMOUS:
            self.set_mode(Mode.PAUSED, cause)

    def check_supervisor(self, client: Client) -> None:
        """An operator (a person's client, not the policy) acting on the autonomy."""
        if client.role is not Role.OPERATOR or client.policy:
            raise NotAllowed("only an operator supervises a policy")
        if self.autonomy.policy_id not in self.clients:
            raise NotAllowed("no policy is connected to supervise")

    def check(self, client: Client) -> None:
        """A policy drives only while a person lets it (``Autonomy.may_drive``: the one
        rule); otherwise its command is refused, counted and said to it (before the
        lease check: it is told why)."""
        if not client.policy:
            return
        if client.id != self.autonomy.policy_id:
            raise NotAllowed("take the control lease before moving the robot")
        self.autonomy.heard_command(self.clock.now())
        if not self.autonomy.may_drive:
            raise self.autonomy.refuse()

    async def hand_to_policy(self, mode: Mode, cause: str, operator: str) -> None:
        """The lease back to the policy, the arm stopped where it is: it drives on from
        there (``AUTONOMOUS``: a person's go, unless the e-stop is latched: then
        ``PAUSED``) or waits for a resume (``PAUSED``)."""
        policy = self.clients.get(self.autonomy.policy_id or "")
        if mode is Mode.AUTONOMOUS and self._estopped():
            mode, cause = Mode.PAUSED, f"{cause}, the e-stop latched: paused until resumed"
        elif mode is Mode.AUTONOMOUS:
            self.autonomy.go()
        else:
            self.autonomy.stopped()
        await self._stop_all()
        self.lease.give(policy, cause)  # its first increment is allowed 0.1 s of speed
        policy.last_seen = self.clock.now()
        self._lease_changed()
        self.set_mode(mode, cause, operator=operator)

    def taken(self, client: Client, taken_from: Client | None) -> None:
        """``client`` took the lease (from ``taken_from``): a policy waits for a
        person's go (a stop event); a person taking it from the policy corrects."""
        if client.policy:
            self.autonomy.stopped()
            self.autonomy.start(client.id, client.name)
            self.set_mode(
                Mode.PAUSED,
                f"{client.name!r} took control; it waits until a person lets it drive",
            )
        elif taken_from is not None and taken_from.id == self.autonomy.policy_id:
            self.set_mode(Mode.CORRECTING, f"taken over by {client.name!r}", operator=client.name)

    async def released(self, client: Client) -> bool:
        """An operator correcting a policy let go: control goes back to the policy
        (``release_to``); False if this release is not a hand-back."""
        if self.autonomy.mode is not Mode.CORRECTING or client.id == self.autonomy.policy_id:
            return False
        paused = self.release_to is ReleaseTo.PAUSE
        await self.hand_to_policy(
            Mode.PAUSED if paused else Mode.AUTONOMOUS,
            f"handed back by {client.name!r}" + (" (paused: autonomy_release)" if paused else ""),
            client.name,
        )
        return True

    async def lapsing(self, why: str) -> bool:
        """The lease is lapsing (a stop event): a correcting operator's goes back to the
        policy, paused (True: handled); the policy's own ends autonomy (False: the lease
        is dropped by the caller)."""
        holder = self.lease.holder
        policy = self.autonomy.policy_id
        self.autonomy.stopped()
        if (
            self.autonomy.mode is Mode.CORRECTING
            and holder is not None
            and holder != policy
            and policy in self.clients
        ):
            known = self.clients.known(holder)
            name = known.name if known is not None else "the operator"
            await self.hand_to_policy(Mode.PAUSED, f"{name}'s control lapsed: {why}", name)
            return True
        if holder is not None and holder == policy:
            self.set_mode(Mode.OFF, f"the policy lost control: {why}")
        return False

    def left(self, client_id: str) -> None:
        """A client left: the policy's leaving ends autonomy (a stop event)."""
        if client_id == self.autonomy.policy_id:
            self.autonomy.stopped()
            self.autonomy.end()
            self.set_mode(Mode.OFF, "the policy left")

    async def pause(self, client: Client) -> None:
        """Hold the policy still (look, think): its commands are refused until resumed.
        From a correction, control goes back to the policy, paused."""
        if self.autonomy.mode is Mode.CORRECTING:
            await self.hand_to_policy(Mode.PAUSED, f"paused by {client.name!r}", client.name)
            return
        self.autonomy.stopped()
        await self._stop_all()
        self.set_mode(Mode.PAUSED, f"paused by {client.name!r}", operator=client.name)

    async def resume(self, client: Client) -> None:
        """The policy drives again, from where the arm is (from a correction: handed
        back). The caller has refused it while the e-stop is latched."""
        cause = f"resumed by {client.name!r}"
        if self.lease.holder != self.autonomy.policy_id:
            await self.hand_to_policy(Mode.AUTONOMOUS, cause, client.name)
        else:
            self.autonomy.go()
            self.set_mode(Mode.AUTONOMOUS, cause, operator=client.name)
