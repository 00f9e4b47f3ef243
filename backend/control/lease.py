"""The control lease and the dead-man over it (thesis §4.3.3): who holds control, why
it last changed hands, and the dead-man's verdict on a silent holder. What a verdict
does (stop the arms, hand control back to a policy) is the DecisionServer's
(``decision.py``); the supervision of a policy over the lease is ``autonomy.py``
(docs/architecture.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from telerobot.drivers.clock import Clock
from telerobot.server.control.clients import Client, ClientTable
from telerobot.server.control.errors import NotAllowed
from telerobot.server.control.limits import SafetyLimits

log = logging.getLogger(__name__)

# A lease holder on a slow link gets its grace lengthened by the time it takes to be
# heard from again once its link is back, in one-way trips at its commands' usual
# transit time: a resume is ~5 (TCP's handshake, the WebSocket upgrade, HELLO; on
# `mobile`, one-way ~120 ms, a 1.5 s cut plus a reconnection ran past a fixed 2 s), and
# TCP's own resends after a cut take longer still: the first comes one RTO (a round
# trip and four times its variance: about two round trips on a jittery link) after the
# loss, the next two RTOs after that, so on `bad` (one-way ~0.25 s loaded) a 1.5 s
# cut was heard from again 3.55 s after the holder's last heartbeat, 0.01 s past a
# grace of six trips: Chromium's page lost the lease (bench.wan, quiet). Twelve cover
# it. The arm is stopped all along, so only who may take control over waits longer.
# Bounded, so a cut of the grace plus a second still releases the lease on any link.
RETRANSMIT_ONE_WAYS = 12
# …or by the longest silence its link has kept it in over the last STALLS_WINDOW_S,
# whichever is longer: on a lossy narrow link (bench.wan's `bad`) a TCP connection
# stalls 0.4–2.6 s at a time, so a cut's silence begins before the cut and its
# resume arrives late; five such runs were silent 2.5–3.2 s against a limit of
# 3.15 s, the last one losing the lease by 64 ms. The arm is stopped after 150 ms
# whatever the grace: this decides only how long another may not take over.
STALLS_WINDOW_S = 30.0  # (clients.STALLS_KEPT of them at most)
MAX_GRACE_EXTENSION_S = 3.0


@dataclass(frozen=True)
class Verdict:
    """The dead-man's verdict on a silent holder: its arms stopped with the lease kept
    (``lapse`` False), or the lease taken from it (``why``: what is said)."""

    lapse: bool
    why: str = ""


class Lease:
    """Who holds control (a client id, or None), and the dead-man's state over it."""

    def __init__(self, clients: ClientTable, clock: Clock, limits: SafetyLimits) -> None:
        self.clients = clients
        self.clock = clock
        self.limits = limits
        self.holder: str | None = None
        self.halted = False  # the dead-man stopped the arm; the lease is in its grace
        self.note = ""  # why control last changed hands (or was lost)
        self.halts = 0  # arms stopped by the dead-man with the lease kept
        self._last_tick: float | None = None
        self._deferred = False  # the last tick left its verdict to this one
        self._last_sweep = clock.now()

    def give(self, client: Client, note: str) -> None:
        """``client`` holds control from now; its first increment is allowed the speed
        limit's longest interval, not the time since its last command."""
        self.holder, self.halted, self.note = client.id, False, note
        client.last_command_at.clear()

    def drop(self, note: str) -> None:
        self.holder, self.halted, self.note = None, False, note

    def heard(self, client: Client) -> bool:
        """``client`` is heard from now; True if it held the lease halted by the
        dead-man, which it keeps (the arm stays where it stopped until a fresh command
        moves it: a backlog's stale ones are refused)."""
        now = self.clock.now()
        silent = now - client.last_seen
        if client.id == self.holder and silent > self.silence_limit(client):
            client.stalls.append((now, silent))  # its link's, holding control
        client.last_seen = now
        if not (self.halted and client.id == self.holder):
            return False
        self.halted = False
        client.last_command_at.clear()
        log.info("dead-man: %s is back; the lease was kept", client.name)
        return True

    def grace(self, client: Client) -> float:
        """How long past the dead-man's stop ``client`` keeps the lease: the setting,
        plus the time it takes to be heard from after a cut (``RETRANSMIT_ONE_WAYS`` of
        its usual transit, known for a client on our clock) or the longest silence its
        link kept it in over the last ``STALLS_WINDOW_S``, whichever is longer, at most
        ``MAX_GRACE_EXTENSION_S``."""
        extra = 0.0
        if client.synced_clock and client.transit_avg is not None:
            extra = RETRANSMIT_ONE_WAYS * max(0.0, client.transit_avg)
        now = self.clock.now()
        recent = [silent for at, silent in client.stalls if now - at <= STALLS_WINDOW_S]
        extra = max(extra, max(recent, default=0.0))
        return self.limits.lease_grace_s + min(MAX_GRACE_EXTENSION_S, extra)

    def silence_limit(self, client: Client) -> float:
        """How long ``client`` may be silent holding the lease: the dead-man's limit,
        or a scripted lease's idle timeout while its arm is not being jogged."""
        if client.lease_idle_s is None or client.streaming:
            return self.limits.deadman_timeout_s
        return client.lease_idle_s

    @staticmethod
    def runs_again(client: Client, holder: Client) -> bool:
        """A script run again takes its earlier run's lease without ``force``: the holder
        is a script's lease (no connection of its own) with the same name, taken from
        the same address, with no request in flight. A script that ended without
        releasing its lease (a crash, Ctrl-C, a shell block run twice) would otherwise
        be refused by itself until the lease's idle timeout. Anyone else still needs
        ``force``."""
        return (
            holder.id != client.id
            and holder.source == client.source == "rest"
            and holder.idle_expiry_s is not None
            and holder.name == client.name
            and holder.address != ""
            and holder.address == client.address
            and holder.busy == 0
        )

    def takeover(
        self, client: Client, holder: Client, *, force: bool, policy_id: str | None
    ) -> str:
        """Whether ``client`` may take the lease ``holder`` has (``policy_id``: the
        supervised policy's client, if any): why it changes hands, said in the lease's
        note, or NotAllowed. A policy never takes it; a person always may from a
        policy; anyone else takes it only with ``force``, or as a script run again."""
        again = self.runs_again(client, holder)
        if client.policy:
            raise NotAllowed(
                f"{holder.name!r} has control: a policy never takes it from anyone;"
                + (
                    " it drives again when the operator hands control back"
                    if holder.id != policy_id
                    else " wait until its lease lapses"
                )
            )
        if holder.policy and not client.policy:
            force = True  # a person may always take control from a policy
        if not force and not again:
            raise NotAllowed(
                f"{holder.name!r} has control{self.lapses_in(holder)}; take it over"
                " explicitly (force) if you must"
            )
        return (
            f"taken again by {client.name!r} from {client.address} (the same script, "
            "run again while its earlier run's lease was idle)"
            if again and not force
            else f"taken over by {client.name!r}"
        )

    def lapses_in(self, holder: Client) -> str:
        """When an idle script's lease lapses by itself, said in a refusal."""
        if holder.lease_idle_s is None or holder.streaming or holder.busy:
            return ""
        left = holder.lease_idle_s - (self.clock.now() - holder.last_seen)
        return f" (a script's lease: it lapses in {max(left, 0.0):.1f} s without a request)"

    def judge(self) -> Verdict | None:
        """Dead-man: a lease holder silent for ``deadman_timeout_s`` has its arm
        stopped at once; silent ``lease_grace_s`` longer, it loses the lease (a short
        stall of a busy machine costs a stop, not control). A scripted lease idle past
        its own timeout loses it at once. Asked every ``tick_s``; None: nothing to do.

        A tick that comes late says the *server* stalled (its event loop busy, or the
        machine's CPU taken elsewhere), not that the client went quiet: the client's
        heartbeats may be sitting unread in the socket. Such a tick leaves its verdict
        to the next one, after the loop has read what arrived. Never twice in a row: a
        loop that is always late still stops the arm, one tick later at most."""
        now = self.clock.now()
        gap = now - (self._last_tick if self._last_tick is not None else now)
        late = gap > 2 * self.limits.tick_s
        self._last_tick = now
        if now - self._last_sweep >= 1.0:
            self._last_sweep = now
            self.clients.forget_idle(now, self.holder)
        if self.holder is None:
            return None
        holder = self.clients.known(self.holder)
        if holder is None:
            return Verdict(lapse=True, why="controller gone")
        silent = now - holder.last_seen
        limit = self.silence_limit(holder)
        if holder.busy > 0 or silent <= limit:
            self._deferred = False
            return None
        if late and not self._deferred:
            self._deferred = True
            log.info("dead-man verdict deferred: this server stalled for %.0f ms", gap * 1000)
            return None
        self._deferred = False
        scripted = limit != self.limits.deadman_timeout_s
        grace = self.grace(holder)
        if scripted or silent > limit + grace:
            return Verdict(
                lapse=True,
                why=f"dead-man: no heartbeat from {holder.name!r} for {silent * 1000:.0f} ms"
                f" (the limit is {limit * 1000:.0f} ms"
                + ("" if scripted else f", then {grace:.2g} s of grace")
                + ")",
            )
        if self.halted:
            return None
        self.halted = True
        self.halts += 1
        log.info(
            "dead-man: arm stopped, %s silent for %.0f ms; lease kept %.2g s",
            holder.name,
            silent * 1000,
            grace,
        )
        return Verdict(lapse=False)
