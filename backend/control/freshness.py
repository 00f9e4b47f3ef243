"""How old a command is, and whether it is fresh enough to move the arm (docs/architecture.md,
"Commands"): a command that waited on the way longer than the dead-man's limit (sent
before a stall, read after it) or, from a client on our clock, older than
``max_command_age_s``, is dropped and counted; the age of every executed command is
kept, over all clients and per client (``GET /safety``)."""

from __future__ import annotations

import math

from telerobot.drivers.base import InvalidCommand
from telerobot.drivers.clock import Clock
from telerobot.server.control.clients import Client
from telerobot.server.control.errors import SafetyStop
from telerobot.server.control.limits import SafetyLimits
from telerobot.server.telemetry.stats import StreamTally

TRANSIT_BELIEVED_S = 10.0  # a message's transit longer than this is not believed
TRANSIT_SMOOTHING = 0.1  # the usual transit: an exponential average of each command's
# Every executed command's age (synced clients: our clock − its client_time, where it
# goes to the driver), in ms: the last this many over all clients, and per client (a
# bench's own figures: 4096 is 80 s at 50 Hz). A client's is made by its first such
# command (only a lease holder has any): 32 kB each, at most MAX_CLIENTS of them.
EXECUTED_AGE_WINDOW = 10_000
CLIENT_AGE_WINDOW = 4_096


class CommandAges:
    """The checks on a command's age, and the tallies of the ages executed."""

    def __init__(self, clock: Clock, limits: SafetyLimits) -> None:
        self.clock = clock
        self.limits = limits
        self.stale_dropped = 0  # commands dropped as too old (either check)
        # Every executed command's age at the driver (ms), synced clients only.
        self.executed_ms = StreamTally(
            "executed_age", capacity=EXECUTED_AGE_WINDOW, limit=limits.max_command_age_s * 1000
        )

    def check_age(self, client: Client, client_time: float | None, now: float) -> float | None:
        """A synced client's command older than ``max_command_age_s`` is dropped; its
        age otherwise (None: not on our clock, or no send time)."""
        if not client.synced_clock or client_time is None:
            return None
        age, limit = now - client_time, self.limits.max_command_age_s
        if age > limit:
            client.stale_dropped += 1
            self.stale_dropped += 1
            raise SafetyStop(
                f"stale command: sent {age * 1000:.0f} ms ago, older than the "
                f"{limit * 1000:.0f} ms limit; dropped ({client.stale_dropped} so far)"
            )
        return age

    def note_transit(self, client: Client, client_time: float) -> None:
        """A synced client's message sent at ``client_time`` (our clock) arrived now: its
        transit goes into the usual one (``transit_avg``: the lease's grace follows it).
        A heartbeat's too, so the grace fits the link before the first command: on a
        lossy narrow link the first seconds after a take-over are silent the longest.
        A time in the future or more than TRANSIT_BELIEVED_S ago says nothing of the
        link (a client that sends 0): not counted."""
        age = self.clock.now() - client_time
        if not client.synced_clock or not -0.05 <= age <= TRANSIT_BELIEVED_S:
            return
        avg = client.transit_avg
        client.transit_avg = age if avg is None else avg + TRANSIT_SMOOTHING * (age - avg)

    def check_fresh(self, client: Client, client_time: float | None) -> None:
        """Refuse an increment that waited on the way longer than the dead-man's limit
        (sent before a stall, read after it): motion resumes only on fresh commands.
        Its wait is its transit time (our clock at receipt − its own clock) beyond the
        least transit seen from this client, which drifts up by ``TRANSIT_DRIFT``.
        A client on our clock also has every command's age checked against
        ``max_command_age_s``: older ones are dropped and counted."""
        now = self.clock.now()
        # None: a REST call made on behalf of this client (the page's Home button), which
        # carries no send time; it is judged when it arrives, like any REST move.
        if client.synced_clock and client_time is not None:
            if not math.isfinite(client_time):
                raise InvalidCommand("a command without a valid send time (client_time)")
            self.note_transit(client, client_time)
            self.check_age(client, client_time, now)
        if client_time is None or not math.isfinite(client_time):
            return
        transit = now - client_time
        waited = transit - client.transit_floor.update(transit, now)
        if waited > self.limits.deadman_timeout_s:
            # Counted with the age check's drops: every command dropped for its age is
            # in /safety's stale_commands_dropped, whichever check dropped it.
            client.stale_dropped += 1
            self.stale_dropped += 1
            raise SafetyStop(
                f"stale command: it waited {waited * 1000:.0f} ms on the way (longer than "
                f"the dead-man's {self.limits.deadman_timeout_s * 1000:.0f} ms); dropped"
                f" ({client.stale_dropped} so far)"
            )

    def executed(self, client: Client, age: float) -> None:
        """A command of ``client``'s went to the driver ``age`` s after it was sent."""
        self._client_tally(client).record(age * 1000.0)
        self.executed_ms.record(age * 1000.0)

    def _client_tally(self, client: Client) -> StreamTally:
        if client.executed_age is None:
            client.executed_age = StreamTally(
                "executed_age",
                capacity=CLIENT_AGE_WINDOW,
                limit=self.limits.max_command_age_s * 1000,
            )
        return client.executed_age
