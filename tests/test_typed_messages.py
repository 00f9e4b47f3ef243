"""The typed messages (telerobot/protocol/typed.py) against the table in messages.py:
one dataclass per message with the table's fields, the same bytes as the positional
``encode`` and as ``struct`` itself, a round trip through ``parse``, and the same
refusals of malformed input as ``decode``."""

from __future__ import annotations

import dataclasses
import math
import re
import struct
from typing import Any, ClassVar

import pytest

from telerobot.protocol import messages as m
from telerobot.protocol import typed
from telerobot.server.realtime import typescript

SAMPLES = ((7, 1.25, (1.0, -2.0, 3.0, 0.5, -0.25, 0.125)), (8, 1.5, (0.0,) * 6))
TEXT = "left: héllo"
JOINTS = (0.1, -0.2, 0.3, 0.0, 1e-9, -3.0)


def sample_values(spec: m.Message) -> list[Any]:
    """A value for every field of ``spec``, distinct and in range of its struct code."""
    values: list[Any] = []
    for count, code in re.findall(r"(\d*)([BHIds])", spec.fmt):
        if code == "s":
            values.append(bytes(range(1, int(count) + 1)))  # full length: no padding to strip
            continue
        for _ in range(int(count or 1)):
            i = len(values)
            values.append({"B": 1 + i, "H": 300 + i, "I": 70_000 + i, "d": 0.5 - i}[code])
    return values


def tail_of(spec: m.Message) -> tuple[Any, ...]:
    return {"text": (TEXT,), "joints": (JOINTS,), "samples": (SAMPLES,), "": ()}[spec.tail]


def legacy_bytes(spec: m.Message, values: list[Any]) -> bytes:
    if spec.tail == "samples":
        return m.encode_force(SAMPLES, *values)
    return m.encode(spec, *values, text=TEXT, joints=JOINTS)


def struct_bytes(spec: m.Message, values: list[Any]) -> bytes:
    """The layout straight from the table's format, without the package's codec."""
    body = struct.pack("<B" + spec.fmt, spec.type_id, *values)
    if spec.tail == "text":
        return body + TEXT.encode()
    if spec.tail == "joints":
        return body + struct.pack(f"<{len(JOINTS)}d", *JOINTS)
    if spec.tail == "samples":
        rows = b"".join(struct.pack("<Id6d", s, t, *v) for s, t, v in SAMPLES)
        return body + struct.pack("<H", len(SAMPLES)) + rows
    return body


def cls_of(spec: m.Message) -> type[Any]:
    (cls,) = (c for c in typed.CLASSES if c.SPEC is spec)
    return cls


def test_every_message_has_one_dataclass_named_as_its_typescript_interface() -> None:
    assert [c.SPEC for c in typed.CLASSES] == list(m.MESSAGES)
    for spec in m.MESSAGES:
        cls = cls_of(spec)
        assert cls.__name__ == typescript.interface_name(spec)
        params = cls.__dataclass_params__  # type: ignore[attr-defined]
        assert params.frozen and "__slots__" in cls.__dict__, cls.__name__
        assert typed.table_mismatch(cls, spec) == ""


def test_the_unions_split_the_messages_by_direction() -> None:
    client = set(typed.ClientMessage.__args__)
    server = set(typed.ServerMessage.__args__)
    assert client == {cls_of(s) for s in m.MESSAGES if s.type_id < 0x80}
    assert server == {cls_of(s) for s in m.MESSAGES if s.type_id >= 0x80}


@dataclasses.dataclass(frozen=True, slots=True)
class _Ack:  # as AckMessage should be
    SPEC: ClassVar[m.Message] = m.ACK
    seq: int
    result: int
    server_time: float
    scale: float


@dataclasses.dataclass(frozen=True, slots=True)
class _Renamed:
    seq: int
    result: int
    time: float
    scale: float


@dataclasses.dataclass(frozen=True, slots=True)
class _Reordered:
    seq: int
    server_time: float
    result: int
    scale: float


@dataclasses.dataclass(frozen=True, slots=True)
class _OneShort:
    seq: int
    result: int
    server_time: float


@dataclasses.dataclass(frozen=True, slots=True)
class _OneMore:
    seq: int
    result: int
    server_time: float
    scale: float
    extra: int = 0


@dataclasses.dataclass(frozen=True, slots=True)
class _WrongType:
    seq: int
    result: int
    server_time: int
    scale: float


@dataclasses.dataclass(frozen=True, slots=True)
class _Defaulted:
    seq: int
    result: int
    server_time: float
    scale: float = 1.0  # the table gives ACK no default


@pytest.mark.parametrize("bad", [_Renamed, _Reordered, _OneShort, _OneMore, _WrongType, _Defaulted])
def test_a_dataclass_that_disagrees_with_the_table_is_caught(bad: type) -> None:
    assert typed.table_mismatch(_Ack, m.ACK) == ""
    assert typed.table_mismatch(bad, m.ACK) != ""


@pytest.mark.parametrize("spec", m.MESSAGES, ids=lambda s: s.name)
def test_the_same_bytes_as_the_positional_encode_and_a_round_trip(spec: m.Message) -> None:
    values = sample_values(spec)
    message = cls_of(spec)(*values, *tail_of(spec))
    data = message.encode()
    assert data == legacy_bytes(spec, values) == struct_bytes(spec, values)
    assert typed.parse(data) == message
    legacy, fields, text = m.decode(data)
    assert legacy is spec and fields == message.as_dict()
    assert text == (TEXT if spec.tail == "text" else "")


@pytest.mark.parametrize("spec", [s for s in m.MESSAGES if s.defaults], ids=lambda s: s.name)
def test_left_out_fields_take_the_tables_defaults(spec: m.Message) -> None:
    values = sample_values(spec)[: -len(spec.defaults)]
    assert cls_of(spec)(*values).encode() == m.encode(spec, *values)


def malformed_inputs() -> list[bytes]:
    out = [b"", b"\x7f", b"\xff\x00"]
    for spec in m.MESSAGES:
        good = legacy_bytes(spec, sample_values(spec))
        out += [good[:-1], good[: spec.size - 1], good[:3], good + b"\x00" * 9]
        for field in typescript.field_specs(spec):  # every f64, in its place
            at = int(str(field["offset"]))
            if field["kind"] == "f64":
                for bad in (math.nan, math.inf, -math.inf):
                    out.append(good[:at] + struct.pack("<d", bad) + good[at + 8 :])
    joints = m.encode(m.JOINT_INC, 5, 1.0, 1, joints=[0.0, math.nan])
    state = m.encode(m.STATE, *sample_values(m.STATE), joints=[math.inf])
    too_many = m.encode(m.JOINT_INC, 5, 1.0, 1, joints=[0.0] * (m.MAX_JOINTS + 1))
    text = m.encode(m.NAME, 9) + b"\xff\xfe"
    force = m.encode_force(SAMPLES)[:-1]
    return [*out, joints, state, too_many, text, force]


def outcome(fn: Any, data: bytes) -> tuple[str, str, int] | None:
    try:
        fn(data)
    except m.MalformedMessage as exc:
        return str(exc), exc.code, exc.seq
    return None


def test_parse_refuses_what_decode_refuses_the_same_way() -> None:
    refused = 0
    for data in malformed_inputs():
        expected = outcome(m.decode, data)
        assert outcome(typed.parse, data) == expected, data.hex()
        refused += expected is not None
    assert refused > 60  # the cases above are refusals, not a vacuous agreement


def test_nan_is_refused_with_the_commands_seq() -> None:
    data = m.encode(m.CART_INC, 42, 1.0, 0, math.nan, 0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(m.MalformedMessage, match=r"CART_INC\.dx is nan") as caught:
        typed.parse(data)
    assert (caught.value.code, caught.value.seq) == ("invalid_command", 42)


def test_seq_of_a_message_without_one_is_zero() -> None:
    assert typed.seq_of(typed.AckMessage(seq=3, result=0, server_time=0.0, scale=1.0)) == 3
    assert typed.seq_of(typed.EventMessage(kind=1, server_time=0.0)) == 0


def test_no_credential_is_in_a_messages_repr() -> None:
    """The operator token (HELLO), a datagram key (DATAGRAMS) and a resume key (WELCOME's
    text) never show in a repr: a message logged or put in an error says no secret."""
    from telerobot.protocol.typed import DatagramsMessage, HelloMessage, WelcomeMessage

    secret = "s3cret-credential-0123456789"
    said = [
        repr(HelloMessage(version=3, flags=0, token=secret.encode())),
        repr(DatagramsMessage(seq=1, key=secret[:16].encode(), every=1)),
        repr(WelcomeMessage(version=3, role=1, server_time=0.0, joints=6, text=f"c1 {secret}")),
    ]
    assert not any(secret[:16] in s for s in said), said
