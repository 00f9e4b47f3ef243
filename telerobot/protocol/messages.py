"""Every binary WebSocket message, defined once (docs/architecture.md, rule 5).

Little-endian, no padding. Byte 0 is the message type; the rest is a fixed layout
given as a ``struct`` format, except where a message ends in UTF-8 text or a counted
array. docs/protocol.md describes the same table (a test keeps them in step), and
the TypeScript client's types are generated from ``MESSAGES``
(``backend/realtime/typescript.py``; a test keeps them in step too). Python code
builds and reads them as the frozen dataclasses of ``typed.py`` (checked against this
table at import); ``encode``/``decode`` below are the positional form tests use, and
both go through ``pack``/``unpack``.

Client → server types are 0x01–0x7F, server → client 0x81–0xFF.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property
from typing import Any, Final

# 2: joints as a tail, their count in WELCOME. 3: a server drives one arm or more (each
# command names its arm, STATE and FORCE say whose, ARM lists them after WELCOME).
PROTOCOL_VERSION: Final = 3

# Stream framing (the priority channel, any TCP transport): every message preceded by
# its length, u16 little-endian. Here with the messages, so a client (the master-arm
# bridge) imports the protocol without the server.
LENGTH: Final = struct.Struct("<H")


def frame(message: bytes) -> bytes:
    """One message framed for a stream socket."""
    return LENGTH.pack(len(message)) + message


class Frame(IntEnum):
    BASE = 0
    WRIST = 1
    TOOL = 2


class LeaseAction(IntEnum):
    RELEASE = 0
    TAKE = 1
    TAKE_OVER = 2  # forced: takes control from whoever holds it
    # Supervising a policy (an operator only; docs/protocol.md, Supervised autonomy):
    PAUSE = 3  # hold the policy still: its commands refused until RESUME
    RESUME = 4  # the policy drives again (from a correction: control handed back to it)


class HelloFlags(IntEnum):
    EVERY_FORCE_SAMPLE = 1  # one FORCE message per sample instead of ~10 ms batches
    # client_time is on the server's clock (synced with PING/PONG): commands older than
    # the server's max command age are dropped (and one whose time is not a number is
    # refused).
    SYNCED_CLOCK = 2
    # Give me a resume key: WELCOME's text is then "<client id> <resume key>".
    RESUMABLE = 4
    # The token field is a resume key, not the operator token: this HELLO continues that
    # session (its role and its lease, if it still holds it) on a new connection, and
    # the old connection is dropped. For a link that stalled: a new TCP connection gets
    # through at once when the link is back, where the old one may wait out TCP's
    # doubling retransmission timeout (0.2, 0.6, 1.4, 3 s after a loss).
    RESUME = 8
    # This client is a learned policy (needs a policy token; the operator token is
    # refused with it): it drives under supervision, only after a person says go, and
    # any operator takes control from it without forcing.
    POLICY = 16


class StateFlags(IntEnum):
    YOU_HAVE_CONTROL = 1
    SOMEONE_HAS_CONTROL = 2
    ESTOP = 4
    FORCE_LIMITED = 8
    OPERATOR = 16  # you joined with a token that drives (the operator's, or a policy's)
    HALTED = 32  # the dead-man stopped the arm; its holder keeps the lease for a grace period


class Ack(IntEnum):
    APPLIED = 0
    LIMITED = 1  # applied, scaled down by the speed limit


class EventKind(IntEnum):
    STATUS = 1  # robot status changed: text is "STATUS: message"
    LEASE = 2  # who has control changed
    SAFETY = 3  # e-stop / force limit changed
    INFO = 4
    AUTONOMY = 5  # a policy's supervision changed: text is JSON (mode, policy, operator, cause…)


@dataclass(frozen=True)
class Message:
    name: str
    type_id: int
    fields: tuple[str, ...]  # names of the struct fields after the type byte
    fmt: str  # struct format of those fields (without the leading '<B')
    # "text" (UTF-8 to the end), "samples" (u16 count + FORCE_SAMPLE each) or "joints"
    # (f64 each to the end: as many as WELCOME's ``joints`` says the arm has)
    tail: str = ""
    doc: str = ""
    # Values of the last fields when a sender leaves them out (``encode``): the arm
    # index, added in version 3 at the end, is 0 (the only arm) unless named.
    defaults: tuple[object, ...] = ()

    @cached_property  # compiled once: every encode and decode on the 1 kHz paths uses it
    def struct(self) -> struct.Struct:
        return struct.Struct("<B" + self.fmt)

    @property
    def size(self) -> int:
        return self.struct.size


# One force sample inside a FORCE message: seq, sensor time (s), Fx Fy Fz (N), Tx Ty Tz (N·m).
FORCE_SAMPLE: Final = struct.Struct("<Id6d")

HELLO = Message(
    "HELLO",
    0x01,
    ("version", "flags", "token"),
    "HH64s",
    doc="first message; the operator token (printable ASCII, ≤ 64 bytes) zero-padded, or empty",
)
CART_INC = Message(
    "CART_INC",
    0x02,
    ("seq", "client_time", "frame", "dx", "dy", "dz", "rx", "ry", "rz", "arm"),
    "IdB3d3dB",
    doc="ΔX (m) and ΔM as a rotation vector (rad) in the given frame, for the arm"
    " (ARM's index; 0: the only arm, refused on a server with more)",
    defaults=(0,),
)
JOINT_INC = Message(
    "JOINT_INC",
    0x03,
    ("seq", "client_time", "arm"),
    "IdB",
    tail="joints",
    doc="joint increments (rad), one per joint of the arm (ARM's joints; arm as in CART_INC)",
    defaults=(0,),
)
HEARTBEAT = Message(
    "HEARTBEAT",
    0x04,
    ("seq", "client_time"),
    "Id",
    doc="keeps the dead-man satisfied (any message does)",
)
ESTOP = Message("ESTOP", 0x05, ("seq", "client_time"), "Id", doc="latched stop; anyone may send it")
PING = Message("PING", 0x06, ("seq", "t0"), "Id", doc="clock sync: the client's send time")
LEASE = Message("LEASE", 0x07, ("seq", "action"), "IB", doc="take, release or take over control")
RESET = Message("RESET", 0x08, ("seq",), "I", doc="clear a latched e-stop (the client in control)")
DATAGRAMS = Message(
    "DATAGRAMS",
    0x09,
    ("seq", "key", "every"),
    "I16sH",
    doc="priority channel only, operators only: on TCP, send my forces as UDP datagrams"
    " (key: zeros), answered by a DATAGRAMS with the server's key, new each time; on UDP"
    " to the channel's port, that key, from the socket that receives them (on the TCP"
    " connection's IP address), at least every second; every: send one sample in this"
    " many (1 = all; a slow link asks for fewer)",
)
NAME = Message(
    "NAME",
    0x0A,
    ("seq",),
    "I",
    tail="text",
    doc="the name this client goes by from now on, shown wherever control is listed (UTF-8,"
    " 1–64 characters: letters, digits, spaces and . , : _ - @ # + / '); ACK, or ERROR"
    " saying why (the name is kept)",
)
ENERGY = Message(
    "ENERGY",
    0x0B,
    ("seq", "e_in", "e_out", "arm"),
    "IddB",
    doc="a master arm's side of the two-port passivity: the energy its operator has put"
    " into the link so far (e_in) and got back from it (e_out), J in the arm's units,"
    " since the connection opened; from the first, the arm keeps to it"
    " (docs/protocol.md, Passivity); answered by PORT_ENERGY; arm as in CART_INC",
    defaults=(0,),
)

WELCOME = Message(
    "WELCOME",
    0x81,
    ("version", "role", "server_time", "joints", "arms"),
    "HBdBB",
    tail="text",
    doc="role 1 = operator; joints: how many the first arm has; arms: how many arms the"
    " server drives (an ARM message for each follows at once); text = client id",
    defaults=(1,),
)
STATE = Message(
    "STATE",
    0x82,
    (
        "seq",
        "server_time",
        "status",
        "flags",
        "x",
        "y",
        "z",
        "r00",
        "r01",
        "r02",
        "r10",
        "r11",
        "r12",
        "r20",
        "r21",
        "r22",
        "arm",
    ),
    "IdBB3d9dB",
    tail="joints",
    doc="one arm's state (every arm's, each tick); status: index in RobotStatus order;"
    " flags: StateFlags (FORCE_LIMITED and HALTED for this arm); pose in the arm's own base"
    " frame; arm: ARM's index; then the joints (rad)",
    defaults=(1,),
)
FORCE = Message(
    "FORCE",
    0x83,
    ("arm",),
    "B",
    tail="samples",
    doc="the force sensor of the arm (ARM's index): u16 count, then count × (u32 seq,"
    " f64 time, 6 × f64)",
)
EVENT = Message(
    "EVENT",
    0x84,
    ("kind", "server_time"),
    "Bd",
    tail="text",
    doc="something happened; text says what",
)
ERROR = Message(
    "ERROR",
    0x85,
    ("seq", "code"),
    "IH",
    tail="text",
    doc="the command with this seq was refused; nothing moved",
)
ACK = Message(
    "ACK",
    0x86,
    ("seq", "result", "server_time", "scale"),
    "IBdd",
    doc="the command reached the driver; server_time: as the driver's call returned (its"
    " age at the driver is age_ms on /commands); scale: the share of an increment"
    " applied (1 unless the speed limit scaled it down: LIMITED)",
)
PONG = Message(
    "PONG",
    0x87,
    ("seq", "t0", "t1", "t2"),
    "Iddd",
    doc="t0 echoed, t1 server receive, t2 server send",
)
PORT_ENERGY = Message(
    "PORT_ENERGY",
    0x88,
    ("seq", "e_in", "e_out"),
    "Idd",
    doc="the arm's side, answering ENERGY (its seq): the energy the arm's surroundings"
    " have given back into the link (e_in) and the arm has put into them (e_out), J,"
    " cumulative; the master renders no more than e_in",
)

ARM = Message(
    "ARM",
    0x89,
    ("index", "joints"),
    "BB",
    tail="text",
    doc="one arm the server drives, right after WELCOME (one each, in order from index 1):"
    " its joint count; text = its name (left, right…), which REST calls take",
)

MESSAGES: Final[tuple[Message, ...]] = (
    HELLO, CART_INC, JOINT_INC, HEARTBEAT, ESTOP, PING, LEASE, RESET, DATAGRAMS, NAME, ENERGY,
    WELCOME, STATE, FORCE, EVENT, ERROR, ACK, PONG, PORT_ENERGY, ARM,
)  # fmt: skip
BY_ID: Final = {m.type_id: m for m in MESSAGES}

# ERROR codes: stable numbers for the error kinds a client may see.
ERROR_CODES: Final = {
    "malformed": 1,
    "unknown_type": 2,
    "invalid_command": 3,
    "unreachable_pose": 4,
    "joint_limit": 5,
    "limit_exceeded": 6,
    "not_ready": 7,
    "not_allowed": 8,
    "safety_stop": 9,
    "device_error": 10,
    "telerobot_error": 11,
}


class MalformedMessage(ValueError):
    def __init__(self, message: str, code: str = "malformed", seq: int = 0) -> None:
        super().__init__(message)
        self.code = code
        self.seq = seq


# The most joints a message may carry (a JOINT_INC or STATE past it is malformed).
MAX_JOINTS: Final = 16


# A message's tail as ``unpack`` returns it: its text, its joints, or its force samples
# (None for a message without one).
ForceSampleTuple = tuple[int, float, tuple[float, ...]]
Tail = str | tuple[float, ...] | tuple[ForceSampleTuple, ...] | None


def pack(
    msg: Message, values: Sequence[object], text: str = "", joints: Sequence[float] = ()
) -> bytes:
    """``values``: every field of ``msg``, in order (the codec both ``encode`` and the
    dataclasses of ``typed.py`` use, so their bytes cannot differ)."""
    body = msg.struct.pack(msg.type_id, *values)
    if msg.tail == "text":
        return body + text.encode("utf-8")
    if msg.tail == "joints":
        return body + struct.pack(f"<{len(joints)}d", *joints)
    return body


def encode(msg: Message, *values: object, text: str = "", joints: Sequence[float] = ()) -> bytes:
    """``values`` in field order; the last ones may be left out where ``msg.defaults``
    has them (a one-arm sender need not name its arm). The typed messages
    (``telerobot.protocol.typed``) are the product code's way; tests and benches use this."""
    missing = len(msg.fields) - len(values)
    if 0 < missing <= len(msg.defaults):
        values = (*values, *msg.defaults[len(msg.defaults) - missing :])
    return pack(msg, values, text, joints)


FORCE_HEAD: Final = struct.Struct("<BBH")  # type, arm, count


def encode_force(samples: Sequence[ForceSampleTuple], arm: int = 1) -> bytes:
    out = bytearray(FORCE_HEAD.pack(FORCE.type_id, arm, len(samples)))
    for seq, t, values in samples:
        out += FORCE_SAMPLE.pack(seq & 0xFFFFFFFF, t, *values)
    return bytes(out)


def force_arm(data: bytes) -> int:
    """The arm index of a FORCE message (its second byte)."""
    if len(data) < FORCE_HEAD.size or data[0] != FORCE.type_id:
        raise MalformedMessage("not a FORCE message")
    return data[1]


def decode_force(data: bytes) -> list[ForceSampleTuple]:
    if len(data) < FORCE_HEAD.size or data[0] != FORCE.type_id:
        raise MalformedMessage("not a FORCE message")
    _, _, count = FORCE_HEAD.unpack_from(data)
    head = FORCE_HEAD.size
    if len(data) != head + count * FORCE_SAMPLE.size:
        raise MalformedMessage(
            f"FORCE with {count} samples must be {head + count * FORCE_SAMPLE.size} bytes"
        )
    return [
        (s[0], s[1], tuple(s[2:]))
        for s in (
            FORCE_SAMPLE.unpack_from(data, head + i * FORCE_SAMPLE.size) for i in range(count)
        )
    ]


def _wrong_size(msg: Message, data: bytes) -> MalformedMessage:
    seq = struct.unpack_from("<I", data, 1)[0] if len(data) >= 5 and "seq" in msg.fields[:1] else 0
    wanted = f"{msg.size} + 8 × joints (≤ {MAX_JOINTS})" if msg.tail == "joints" else str(msg.size)
    return MalformedMessage(f"{msg.name} must be {wanted} bytes, got {len(data)}", seq=seq)


def _check_finite(msg: Message, values: tuple[Any, ...], joints: tuple[float, ...]) -> None:
    """NaN and infinity are refused in every number (a command carrying one must not move
    anything), with the seq so the client knows which command it was."""
    # The common case in one pass of C (this runs for every message on the 1 kHz paths);
    # bytes fields (a HELLO's token) are not numbers, so those messages take the loop.
    if all(map(math.isfinite, joints)) and ("s" not in msg.fmt and all(map(math.isfinite, values))):
        return
    for name, v in zip(msg.fields, values, strict=True):
        if isinstance(v, float) and not math.isfinite(v):
            raise MalformedMessage(
                f"{msg.name}.{name} is {v}", "invalid_command", _seq(msg, values)
            )
    if not all(map(math.isfinite, joints)):
        raise MalformedMessage(
            f"{msg.name}.joints has NaN or infinity", "invalid_command", _seq(msg, values)
        )


def _seq(msg: Message, values: tuple[Any, ...]) -> int:
    return int(values[msg.fields.index("seq")]) if "seq" in msg.fields else 0


def unpack(data: bytes) -> tuple[Message, tuple[Any, ...], Tail]:
    """Parse and check one message: its definition, its field values in order, and its
    tail (None without one). Both ``decode`` and ``typed.parse`` are this, so they
    refuse the same bytes the same way.

    Raises ``MalformedMessage`` (with the seq when it can be read) for an empty frame,
    an unknown type, a wrong size, or a NaN/infinite number.
    """
    if not data:
        raise MalformedMessage("empty message")
    msg = BY_ID.get(data[0])
    if msg is None:
        raise MalformedMessage(f"unknown message type 0x{data[0]:02x}", "unknown_type")
    if msg.tail == "samples":
        samples = tuple(decode_force(data))  # (checks the size first)
        return msg, (data[1],), samples
    size = msg.size
    extra = len(data) - size
    if extra < 0 or (
        extra != 0
        if msg.tail == ""
        else msg.tail == "joints" and (extra % 8 != 0 or extra > 8 * MAX_JOINTS)
    ):
        raise _wrong_size(msg, data)
    values = msg.struct.unpack_from(data)[1:]
    joints: tuple[float, ...] = (
        struct.unpack_from(f"<{extra // 8}d", data, size) if msg.tail == "joints" else ()
    )
    _check_finite(msg, values, joints)
    if msg.tail == "joints":
        return msg, values, joints
    if msg.tail != "text":
        return msg, values, None
    try:
        return msg, values, data[size:].decode("utf-8")
    except UnicodeDecodeError:
        raise MalformedMessage(f"{msg.name} text is not UTF-8") from None


def decode(data: bytes) -> tuple[Message, dict[str, Any], str]:
    """Parse one message: its definition, its fields by name (a JOINT_INC's or STATE's
    joints as ``joints``; a FORCE's only its arm: ``decode_force`` has its samples), and
    its text tail. The errors are ``unpack``'s."""
    msg, values, tail = unpack(data)
    fields: dict[str, Any] = dict(zip(msg.fields, values, strict=True))
    if msg.tail == "joints":
        fields["joints"] = tail
    return msg, fields, tail if isinstance(tail, str) else ""


def markdown_table() -> str:
    """The message table of docs/protocol.md: ``python -m telerobot.protocol.messages``."""
    rows = [
        "| message | type | layout (struct) | bytes | fields | meaning |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for msg in MESSAGES:
        size = {
            "text": f"{msg.size} + text",
            "samples": "4 + 60 × n",
            "joints": f"{msg.size} + 8 × joints",
        }.get(msg.tail, str(msg.size))
        fields = ", ".join(msg.fields) + (", count: u16, samples" if msg.tail == "samples" else "")
        layout = f"`<B{msg.fmt}`"
        rows.append(
            f"| `{msg.name}` | 0x{msg.type_id:02x} | {layout} | {size} | {fields} | {msg.doc} |"
        )
    return "\n".join(rows)


if __name__ == "__main__":
    print(markdown_table())
