"""What the DecisionServer says of each command: ``Applied``, a command that reached
the driver (its ACK), and ``CommandReport``, every command as it was decided,
accepted or refused, on ``events.command`` (the recording's ``/commands``), made by
the ``reported`` decorator around each command of the DecisionServer (decision.py).

Apart from decision.py because a report is about the command, not a step of deciding
it: the decorator leaves the command unchanged and only says what became of it."""

from __future__ import annotations

import functools
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Concatenate, ParamSpec, TypeVar

from telerobot.drivers.base import FloatArray, TelerobotError

if TYPE_CHECKING:
    from telerobot.server.control.decision import DecisionServer


@dataclass(frozen=True)
class Applied:
    """A command that reached the driver."""

    client_id: str
    seq: int
    client_time: float | None  # the client's own clock, as sent
    applied_at: float  # server clock as the driver's call returned (the ACK's server_time)
    limited: bool  # the speed limit scaled it down
    target: FloatArray
    scale: float = 1.0  # the share of the increment applied (below 1 when limited)
    arm: str = "arm"  # which arm (its name)
    # Its age as it went to the driver: our clock − client_time, taken by the last age
    # check, the driver's call next with no await between (s). None: its client is not
    # on our clock, or it carries no send time (REST, tasks).
    age: float | None = None


@dataclass(frozen=True)
class CommandReport:
    """One command as the DecisionServer decided it (the recording's ``/commands``):
    ``args`` as received (arrays as they came), ``error`` None if it was accepted."""

    t: float  # server clock when decided
    kind: str
    client_id: str | None
    client: str
    source: str
    args: dict[str, Any]
    error: TelerobotError | None
    target: FloatArray | None  # what reached the driver
    lease_holder: str | None
    # Who drives: "policy" (a learned policy's client), "operator" (anyone else, a
    # task included) or "server"; and the autonomy mode it was decided in.
    role: str = "operator"
    autonomy: str = "off"
    age: float | None = None  # an executed command's age at the driver (Applied.age), s


P = ParamSpec("P")
R = TypeVar("R")


def reported(
    kind: str, **extra: str
) -> Callable[
    [Callable[Concatenate[DecisionServer, Any, P], Awaitable[R]]],
    Callable[Concatenate[DecisionServer, Any, P], Awaitable[R]],
]:
    """Every command, accepted or refused, is reported once on ``events.command``
    (the one hook the recorder listens to); the command itself is unchanged."""

    def wrap(
        method: Callable[Concatenate[DecisionServer, Any, P], Awaitable[R]],
    ) -> Callable[Concatenate[DecisionServer, Any, P], Awaitable[R]]:
        @functools.wraps(method)
        async def run(
            self: DecisionServer, client_id: Any, /, *args: P.args, **kwargs: P.kwargs
        ) -> R:
            try:
                result = await method(self, client_id, *args, **kwargs)
            except TelerobotError as exc:
                report(self, kind, client_id, args, {**extra, **kwargs}, exc, None)
                raise
            report(self, kind, client_id, args, {**extra, **kwargs}, None, result)
            return result

        return run

    return wrap


def report(
    server: DecisionServer,
    kind: str,
    client_id: str | None,
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
    error: TelerobotError | None,
    result: object,
) -> None:
    """One command's report on ``server.events.command``: who sent it, as what, what
    it asked (``args``, ``kwargs``: a ``source`` there names where a client-less
    command came from), and what it came to."""
    client = server.clients.known(client_id)
    source = str(kwargs.pop("source", "server"))
    if args:
        kwargs["args"] = list(args)
    server.events.command.emit(
        CommandReport(
            server.clock.now(),
            kind,
            client_id,
            client.name if client else "server",
            client.source if client else source,
            kwargs,
            error,
            result.target if isinstance(result, Applied) else None,
            server.lease.holder,
            "policy"
            if client is not None and client.policy
            else ("operator" if client is not None else "server"),
            server.autonomy.mode.value,
            result.age if isinstance(result, Applied) else None,
        )
    )
