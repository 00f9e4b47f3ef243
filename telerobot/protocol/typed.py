"""Every wire message as a frozen dataclass, in step with the table in ``messages.py``.

``messages.py`` stays the one definition (docs/architecture.md, rule 5): its table gives
the layout, the TypeScript types and docs/protocol.md. Here each message gets a class
named as the TypeScript interface is (``CART_INC`` → ``CartIncMessage``) whose fields
are the table's, in its order, then its tail (``text``, ``joints`` or ``samples``).
A class that disagrees with the table in names, order, count, types or defaults fails
at import (``table_mismatch``), so a change to the table cannot leave these behind.

``parse`` returns one of them (the union ``AnyMessage``: ``ClientMessage`` or
``ServerMessage``), so a dispatch can ``match`` on the class and let mypy prove, with
``typing.assert_never``, that every kind is handled. Both directions go through
``messages.pack`` and ``messages.unpack``: the bytes, and the refusals of malformed
input, are those of the positional ``messages.encode``/``decode``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from operator import attrgetter
from typing import Any, ClassVar, TypeVar

from telerobot.protocol import messages as m
from telerobot.protocol.messages import ForceSampleTuple

# The Python type of each struct code (``s`` is a zero-padded byte string), and of
# each tail: what a dataclass's annotations must say (they are strings here).
_CODE_TYPES = {"B": "int", "H": "int", "I": "int", "d": "float", "s": "bytes"}
_TAIL_TYPES = {
    "text": "str",
    "joints": "tuple[float, ...]",
    "samples": "tuple[ForceSampleTuple, ...]",
}
# What a tail is when a sender leaves it out (``messages.encode``'s defaults); FORCE's
# samples have none: a FORCE without them means nothing.
_TAIL_DEFAULTS: dict[str, object] = {"text": "", "joints": ()}


def _field_types(spec: m.Message) -> list[str]:
    """One type per field of ``spec``: ``3d`` is three floats, ``64s`` one bytes."""
    types: list[str] = []
    count = ""
    for char in spec.fmt:
        if char.isdigit():
            count += char
            continue
        types += [_CODE_TYPES[char]] * (1 if char == "s" else int(count or 1))
        count = ""
    return types


def table_mismatch(cls: type, spec: m.Message) -> str:
    """How ``cls``'s fields disagree with ``spec`` (names, order, count, types,
    defaults); "" when they agree."""
    tail = [spec.tail] if spec.tail else []
    want = [
        *zip(spec.fields, _field_types(spec), strict=True),
        *((name, _TAIL_TYPES[name]) for name in tail),
    ]
    have = [(f.name, str(f.type)) for f in dataclasses.fields(cls)]
    if have != want:
        return f"{cls.__name__} has fields {have}, the table says {want}"
    n = len(spec.fields)
    defaults = [None] * (n - len(spec.defaults)) + [(d,) for d in spec.defaults]
    defaults += [(_TAIL_DEFAULTS[t],) if t in _TAIL_DEFAULTS else None for t in tail]
    got = [
        None if f.default is dataclasses.MISSING else (f.default,) for f in dataclasses.fields(cls)
    ]
    if got != defaults:
        return f"{cls.__name__} has defaults {got}, the table says {defaults}"
    return ""


class _Wire:
    """What every message class shares: its spec, and its bytes."""

    __slots__ = ()
    SPEC: ClassVar[m.Message]
    # The table's fields of an instance, in order (an ``attrgetter``: one C call).
    _values: ClassVar[Callable[[Any], tuple[Any, ...]]]

    def encode(self) -> bytes:
        return m.pack(self.SPEC, type(self)._values(self))

    def as_dict(self) -> dict[str, Any]:
        """The fields as ``messages.decode`` gives them (for callers that take a dict)."""
        fields = dict(zip(self.SPEC.fields, type(self)._values(self), strict=True))
        if self.SPEC.tail == "joints":
            fields["joints"] = getattr(self, "joints")  # noqa: B009 (a subclass's field)
        return fields


class _WithText(_Wire):
    __slots__ = ()
    text: str

    def encode(self) -> bytes:
        return m.pack(self.SPEC, type(self)._values(self), text=self.text)


class _WithJoints(_Wire):
    __slots__ = ()
    joints: tuple[float, ...]

    def encode(self) -> bytes:
        return m.pack(self.SPEC, type(self)._values(self), joints=self.joints)


_BY_TYPE: dict[int, type[_Wire]] = {}
_W = TypeVar("_W", bound=_Wire)


def _wire(cls: type[_W]) -> type[_W]:
    """Check ``cls`` against its table entry and register it for ``parse``."""
    problem = table_mismatch(cls, cls.SPEC)
    if problem:
        raise TypeError(problem)
    fields = cls.SPEC.fields
    getter = attrgetter(*fields)
    # (attrgetter of one name gives the value, not a 1-tuple). Called as
    # ``type(self)._values(self)``: a function read from the class is not bound.
    cls._values = getter if len(fields) > 1 else lambda obj: (getter(obj),)
    _BY_TYPE[cls.SPEC.type_id] = cls
    return cls


# ------------------------------------------------------------ client → server


@_wire
@dataclass(frozen=True, slots=True)
class HelloMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.HELLO
    version: int
    flags: int  # HelloFlags
    # 64 bytes on the wire, zero-padded by struct; a credential: never in a repr
    token: bytes = dataclasses.field(repr=False)


@_wire
@dataclass(frozen=True, slots=True)
class CartIncMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.CART_INC
    seq: int
    client_time: float
    frame: int  # Frame
    dx: float
    dy: float
    dz: float
    rx: float
    ry: float
    rz: float
    arm: int = 0


@_wire
@dataclass(frozen=True, slots=True)
class JointIncMessage(_WithJoints):
    SPEC: ClassVar[m.Message] = m.JOINT_INC
    seq: int
    client_time: float
    arm: int = 0
    joints: tuple[float, ...] = ()


@_wire
@dataclass(frozen=True, slots=True)
class HeartbeatMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.HEARTBEAT
    seq: int
    client_time: float


@_wire
@dataclass(frozen=True, slots=True)
class EstopMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.ESTOP
    seq: int
    client_time: float


@_wire
@dataclass(frozen=True, slots=True)
class PingMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.PING
    seq: int
    t0: float


@_wire
@dataclass(frozen=True, slots=True)
class LeaseMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.LEASE
    seq: int
    action: int  # LeaseAction


@_wire
@dataclass(frozen=True, slots=True)
class ResetMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.RESET
    seq: int


@_wire
@dataclass(frozen=True, slots=True)
class DatagramsMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.DATAGRAMS
    seq: int
    key: bytes = dataclasses.field(repr=False)  # 16 bytes; a credential: never in a repr
    every: int


@_wire
@dataclass(frozen=True, slots=True)
class NameMessage(_WithText):
    SPEC: ClassVar[m.Message] = m.NAME
    seq: int
    text: str = ""


@_wire
@dataclass(frozen=True, slots=True)
class EnergyMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.ENERGY
    seq: int
    e_in: float
    e_out: float
    arm: int = 0


# ------------------------------------------------------------ server → client


@_wire
@dataclass(frozen=True, slots=True)
class WelcomeMessage(_WithText):
    SPEC: ClassVar[m.Message] = m.WELCOME
    version: int
    role: int
    server_time: float
    joints: int
    arms: int = 1
    # "<client id> <resume key>" when asked for (RESUMABLE): a credential, never in a repr
    text: str = dataclasses.field(default="", repr=False)


@_wire
@dataclass(frozen=True, slots=True)
class StateMessage(_WithJoints):
    SPEC: ClassVar[m.Message] = m.STATE
    seq: int
    server_time: float
    status: int  # index in RobotStatus order
    flags: int  # StateFlags
    x: float
    y: float
    z: float
    r00: float
    r01: float
    r02: float
    r10: float
    r11: float
    r12: float
    r20: float
    r21: float
    r22: float
    arm: int = 1
    joints: tuple[float, ...] = ()


@_wire
@dataclass(frozen=True, slots=True)
class ForceMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.FORCE
    arm: int
    samples: tuple[ForceSampleTuple, ...]

    def encode(self) -> bytes:
        return m.encode_force(self.samples, self.arm)


@_wire
@dataclass(frozen=True, slots=True)
class EventMessage(_WithText):
    SPEC: ClassVar[m.Message] = m.EVENT
    kind: int  # EventKind
    server_time: float
    text: str = ""


@_wire
@dataclass(frozen=True, slots=True)
class ErrorMessage(_WithText):
    SPEC: ClassVar[m.Message] = m.ERROR
    seq: int
    code: int  # ERROR_CODES
    text: str = ""


@_wire
@dataclass(frozen=True, slots=True)
class AckMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.ACK
    seq: int
    result: int  # Ack
    server_time: float
    scale: float


@_wire
@dataclass(frozen=True, slots=True)
class PongMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.PONG
    seq: int
    t0: float
    t1: float
    t2: float


@_wire
@dataclass(frozen=True, slots=True)
class PortEnergyMessage(_Wire):
    SPEC: ClassVar[m.Message] = m.PORT_ENERGY
    seq: int
    e_in: float
    e_out: float


@_wire
@dataclass(frozen=True, slots=True)
class ArmMessage(_WithText):
    SPEC: ClassVar[m.Message] = m.ARM
    index: int
    joints: int
    text: str = ""


ClientMessage = (
    HelloMessage | CartIncMessage | JointIncMessage | HeartbeatMessage | EstopMessage
    | PingMessage | LeaseMessage | ResetMessage | DatagramsMessage | NameMessage | EnergyMessage
)  # fmt: skip
ServerMessage = (
    WelcomeMessage | StateMessage | ForceMessage | EventMessage | ErrorMessage | AckMessage
    | PongMessage | PortEnergyMessage | ArmMessage
)  # fmt: skip
AnyMessage = ClientMessage | ServerMessage

# Every message of the table has its class (a new one in the table fails here).
_missing = [spec.name for spec in m.MESSAGES if spec.type_id not in _BY_TYPE]
if _missing:
    raise TypeError(f"no dataclass in typed.py for {', '.join(_missing)}")
CLASSES: tuple[type[_Wire], ...] = tuple(_BY_TYPE[spec.type_id] for spec in m.MESSAGES)


def parse(data: bytes) -> AnyMessage:
    """One message as its dataclass. Raises ``MalformedMessage`` exactly as
    ``messages.decode`` does (empty, unknown type, wrong size, NaN, text not UTF-8)."""
    spec, values, tail = m.unpack(data)
    cls: Callable[..., AnyMessage] = _BY_TYPE[spec.type_id]  # type: ignore[assignment]
    return cls(*values) if tail is None else cls(*values, tail)


def seq_of(message: AnyMessage) -> int:
    """The message's seq, 0 for one without (HELLO, WELCOME, FORCE, EVENT, ARM)."""
    return int(getattr(message, "seq", 0))
