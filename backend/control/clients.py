"""Who is joined (thesis §4.3.3, the DecisionServer's clients): each connection, REST
script, task and policy is a ``Client`` with a role given by its token, in one bounded
table. The table decides who someone is and forgets those who left; what they may do
(the lease, the dead-man, the supervision of a policy) is decided over it
(``lease.py``, ``autonomy.py``, ``decision.py``; docs/architecture.md)."""

from __future__ import annotations

import secrets
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TypedDict, Unpack

from telerobot.drivers.clock import Clock
from telerobot.server.control.errors import NotAllowed
from telerobot.server.control.policy_tokens import PREFIX as POLICY_TOKEN_PREFIX
from telerobot.server.control.policy_tokens import PolicyTokens
from telerobot.server.control.slave_port import SlavePort
from telerobot.server.security import token_matches
from telerobot.server.telemetry.stats import DriftingFloor, StreamTally

MAX_CLIENTS = 512  # joined clients (every /ws, priority or REST-lease client is one)
RESUME_KEY_BYTES = 24  # a resume key: 192 bits, given once, to the connection that joined
# A client's clock and ours drift apart (crystals differ by up to ~100 ppm): the transit
# floor a stale command is measured against rises this much per second, so a drift of
# its clock behind ours is never taken for a delay.
TRANSIT_DRIFT = 2e-4


class Role(StrEnum):
    OPERATOR = "operator"  # a person's client (the operator token): drives, supervises
    OBSERVER = "observer"  # no token: watches
    # A learned policy (a policy token, HELLO's POLICY flag): drives while the supervision
    # lets it (telerobot.server.control.autonomy), nothing else a person may do.
    POLICY = "policy"


ISSUE_POLICY_TOKEN = (
    "issue a policy token for it (telerobot policy-token new NAME, or POST"
    " /api/v1/policy-tokens): it can only drive, and only while a person lets it"
)


STALLS_KEPT = 32  # a client's recent stalls remembered (lease.py: its grace)


@dataclass
class Client:
    id: str
    name: str
    role: Role
    last_seen: float
    busy: int = 0  # requests in flight (a REST call waiting for its move counts as alive)
    # When its last command reached each arm (by name): the speed limit allows an
    # increment the time since the last one *to that arm*; two arms driven at 100 Hz
    # each, interleaved, must not have the second arm's increments cut to the gap
    # between the two (docs/arms.md).
    last_command_at: dict[str, float] = field(default_factory=dict)
    # A client with no connection of its own (a REST script's lease) is forgotten after
    # this long without a request, unless it holds the lease: a script that crashes
    # without DELETE /lease must not fill the table for good. None: while connected.
    idle_expiry_s: float | None = None
    # A scripted lease (REST): between bounded absolute moves it is kept this long
    # without a request, like a person pausing. Streamed increments (any client) always
    # get the fast dead-man: ``streaming`` says the last command was one.
    lease_idle_s: float | None = None
    streaming: bool = False
    # The least (server receive time − client_time) seen: a command's transit time
    # beyond it is how long it waited on the way (a stalled link's backlog).
    transit_floor: DriftingFloor = field(default_factory=lambda: DriftingFloor(TRANSIT_DRIFT))
    transit_avg: float | None = None  # the usual transit, on our clock (synced clients)
    # Its recent silences longer than the dead-man's limit, (when it was heard again,
    # how long): its link's stalls, which lengthen its lease's grace (lease.py).
    stalls: deque[tuple[float, float]] = field(
        default_factory=lambda: deque(maxlen=STALLS_KEPT), repr=False
    )
    source: str = "ws"  # where it joined: ws, priority, rest, task (the recording says)
    # Its client_time is on our clock (it syncs with PING): its commands' age is known.
    synced_clock: bool = False
    stale_dropped: int = 0  # its commands dropped as too old
    # Its executed commands' ages (ms) as they went to the driver; None until the first.
    executed_age: StreamTally | None = field(default=None, repr=False)
    # The secret that lets this client's session continue on a new connection (HELLO's
    # RESUME flag); None: not resumable. Its generation counts the connections so far.
    resume_key: str | None = field(default=None, repr=False)
    generation: int = 0
    # A master arm's side of the two-port passivity, made by its first ENERGY message.
    # Keyed by the arm it drives (a master per arm: two leaders, two haptic masters).
    ports: dict[str, SlavePort] = field(default_factory=dict, repr=False)
    address: str = ""  # the host it joined from (a script's: who may take its idle lease again)
    # A task's client: the operator it runs for. That operator supervises it, and its
    # heartbeats keep it present while the task holds the lease in its place.
    on_behalf_of: str | None = None
    # The policy token it joined with (its id: revoking the token ends the client).
    policy_token: str | None = None

    @property
    def policy(self) -> bool:
        """A learned policy: it drives under supervision
        (telerobot.server.control.autonomy); an operator takes control from it at will."""
        return self.role is Role.POLICY


class Joining(TypedDict, total=False):
    """How a client joins (each optional): ``idle_expiry_s`` (a client with no connection
    of its own, forgotten after this long idle), ``lease_idle_s`` (a scripted lease's
    idle timeout), ``source`` (ws, priority, rest, task), ``synced_clock`` (its
    client_time is on our clock), ``resumable`` (it gets a resume key), ``address``,
    ``on_behalf_of`` (a task's operator), ``policy`` (it joins as a policy)."""

    idle_expiry_s: float | None
    lease_idle_s: float | None
    source: str
    synced_clock: bool
    resumable: bool
    address: str
    on_behalf_of: str | None
    policy: bool


class ClientTable:
    """Every joined client by id, at most ``max_clients`` (rule 18: a client that
    would pass the bound is refused before anything is made for it)."""

    def __init__(
        self,
        clock: Clock,
        operator_token: str,
        policy_tokens: PolicyTokens | None = None,
        max_clients: int = MAX_CLIENTS,
    ) -> None:
        if len(operator_token) < 16:
            raise ValueError("the operator token must have at least 16 characters")
        self.clock = clock
        self._token = operator_token
        self.policy_tokens = policy_tokens or PolicyTokens()
        self.max_clients = max_clients
        self._clients: dict[str, Client] = {}

    def __repr__(self) -> str:  # never the token
        return f"ClientTable({len(self._clients)} of {self.max_clients} clients)"

    def __len__(self) -> int:
        return len(self._clients)

    def __iter__(self) -> Iterator[Client]:
        return iter(list(self._clients.values()))

    def __contains__(self, client_id: object) -> bool:
        return client_id in self._clients

    def check_token(self, token: str | None) -> bool:
        """Whether ``token`` is the operator token (a person's)."""
        return token_matches(token, self._token)

    def add(
        self, name: str, token: str | None, *, keep: str | None = None, **how: Unpack[Joining]
    ) -> Client:
        """A new client, its role from ``token``; with the table full, idle scripts'
        clients are forgotten first (never ``keep``: the lease holder)."""
        role = self.role(token, how.get("policy", False))
        if len(self._clients) >= self.max_clients:
            self.forget_idle(self.clock.now(), keep)
        if len(self._clients) >= self.max_clients:
            raise NotAllowed(
                f"this server already has {self.max_clients} clients: try again when one leaves"
            )
        client = Client(
            secrets.token_hex(8),
            name[:64],
            role,
            self.clock.now(),
            idle_expiry_s=how.get("idle_expiry_s"),
            lease_idle_s=how.get("lease_idle_s"),
            source=how.get("source", "ws"),
            synced_clock=how.get("synced_clock", False),
            resume_key=secrets.token_urlsafe(RESUME_KEY_BYTES)
            if how.get("resumable", False)
            else None,
            address=how.get("address", ""),
            on_behalf_of=how.get("on_behalf_of"),
        )
        if role is Role.POLICY:
            issued = self.policy_tokens.match(token)
            client.policy_token = issued.id if issued else None
        self._clients[client.id] = client
        return client

    def role(self, token: str | None, policy: bool) -> Role:
        """Who a token makes a client: the operator token a person (never a policy: a
        policy gets a token that can only drive), a policy token a policy (only as one)."""
        if self.check_token(token):
            if policy:
                raise NotAllowed(
                    "the operator token cannot join as a policy (it could reset the e-stop"
                    f" and resume itself): {ISSUE_POLICY_TOKEN}"
                )
            return Role.OPERATOR
        if self.policy_tokens.match(token) is not None:
            if not policy:
                raise NotAllowed(
                    "a policy token joins only as a policy (HELLO's POLICY flag, or"
                    " policy: true on POST /lease); a person uses the operator token"
                )
            return Role.POLICY
        if policy:
            revoked = token is not None and token.startswith(POLICY_TOKEN_PREFIX)
            raise NotAllowed(
                "this policy token is not valid (revoked?): " + ISSUE_POLICY_TOKEN
                if revoked
                else f"a policy needs a policy token: {ISSUE_POLICY_TOKEN}"
            )
        return Role.OBSERVER

    def joined_with(self, policy_token: str) -> list[str]:
        """The ids of the clients that joined with this policy token (by its id)."""
        return [c.id for c in self._clients.values() if c.policy_token == policy_token]

    def resumable(self, key: str) -> Client:
        """The client whose resume key this is, its generation moved on (the old
        connection's session is superseded). Every key is compared (no early exit)."""
        found = None
        for client in self._clients.values():  # bounded by max_clients
            if client.resume_key is not None and token_matches(key, client.resume_key):
                found = client
        if found is None:
            raise NotAllowed(
                "no session to resume with this key: it has ended (its connection closed"
                " or the server restarted); connect afresh"
            )
        found.generation += 1
        return found

    def forget_idle(self, now: float, keep: str | None) -> None:
        """Forget the clients with no connection of their own (REST scripts) idle past
        their expiry, with no request in flight; never ``keep`` (the lease holder)."""
        for client in list(self._clients.values()):
            if (
                client.idle_expiry_s is not None
                and client.id != keep
                and client.busy == 0
                and now - client.last_seen > client.idle_expiry_s
            ):
                del self._clients[client.id]

    def get(self, client_id: str) -> Client:
        """The client by this id; NotAllowed if none is joined."""
        try:
            return self._clients[client_id]
        except KeyError:
            raise NotAllowed(f"unknown client {client_id!r}: join first") from None

    def known(self, client_id: str | None) -> Client | None:
        """The client by this id, if one is joined (a read that must not fail)."""
        return self._clients.get(client_id) if client_id is not None else None

    def remove(self, client_id: str) -> None:
        self._clients.pop(client_id, None)
