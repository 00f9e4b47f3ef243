"""The Feetech SCS/STS bus protocol ("protocol 0", the STS3215's), bytes only, no I/O.

Instruction packet: ``FF FF ID LEN INST P1..Pn CHK``; status packet (a servo's reply):
``FF FF ID LEN ERR D1..Dn CHK``. ``LEN`` = n + 2, ``CHK`` = ``~(ID + LEN + INST/ERR +
ΣP) & 0xFF``. Multi-byte registers are little-endian; signed registers are
sign-magnitude (a sign bit, not two's complement). ``SYNC_READ`` (to the broadcast id)
is answered by one ordinary status packet per listed servo, in the order listed;
``SYNC_WRITE`` and anything sent to the broadcast id get no answer.

Values and layouts follow Feetech's SDK (``scservo_sdk``) and LeRobot's control table
for the STS series; nothing here is copied from them.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

HEADER = b"\xff\xff"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
# The SDK refuses a status packet longer than this (LEN byte); so do we, so that a
# garbled length never makes a reader wait for 255 bytes that will not come.
MAX_LENGTH = 250
MIN_PACKET = 6  # FF FF ID LEN ERR CHK

STS3215_MODEL = 777
STEPS_PER_TURN = 4096
DEFAULT_BAUDRATE = 1_000_000


class Instruction(enum.IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


class Register(enum.IntEnum):
    """STS3215 control table addresses (EPROM below 40, SRAM from 40)."""

    MODEL_NUMBER = 3  # 2 bytes, read only
    ID = 5
    BAUD_RATE = 6
    RETURN_DELAY_TIME = 7  # units of 2 µs
    MIN_POSITION_LIMIT = 9  # 2
    MAX_POSITION_LIMIT = 11  # 2
    HOMING_OFFSET = 31  # 2, sign bit 11: Present_Position = actual − offset
    OPERATING_MODE = 33
    TORQUE_ENABLE = 40
    ACCELERATION = 41  # units of 100 steps/s²; 0 = the servo's maximum
    GOAL_POSITION = 42  # 2, sign bit 15
    GOAL_TIME = 44  # 2, ms; 0 = use the goal velocity
    GOAL_VELOCITY = 46  # 2, steps/s, sign bit 15
    LOCK = 55  # 0: EPROM writable
    PRESENT_POSITION = 56  # 2, sign bit 15
    PRESENT_VELOCITY = 58  # 2, steps/s, sign bit 15
    PRESENT_LOAD = 60  # 2, 0.1 % of the maximum torque, sign bit 10
    PRESENT_VOLTAGE = 62  # 0.1 V
    PRESENT_TEMPERATURE = 63  # °C
    STATUS = 65
    MOVING = 66
    PRESENT_CURRENT = 69  # 2


SIGN_BITS: Mapping[Register, int] = {
    Register.HOMING_OFFSET: 11,
    Register.GOAL_POSITION: 15,
    Register.GOAL_VELOCITY: 15,
    Register.PRESENT_POSITION: 15,
    Register.PRESENT_VELOCITY: 15,
    Register.PRESENT_LOAD: 10,
}


class ErrorBit(enum.IntFlag):
    """The ERR byte of a status packet (the SDK's names; bits 4 and 6 are undocumented)."""

    VOLTAGE = 0x01
    ANGLE_SENSOR = 0x02
    OVERHEAT = 0x04
    OVERCURRENT = 0x08
    OVERLOAD = 0x20


ERROR_TEXT: Mapping[ErrorBit, str] = {
    ErrorBit.VOLTAGE: "input voltage out of range",
    ErrorBit.ANGLE_SENSOR: "angle sensor fault",
    ErrorBit.OVERHEAT: "overheating",
    ErrorBit.OVERCURRENT: "over-current",
    ErrorBit.OVERLOAD: "overload",
}


def error_names(bits: int) -> list[str]:
    """What the ERR byte says, in words (unknown bits by their value)."""
    names = [text for bit, text in ERROR_TEXT.items() if bits & bit]
    unknown = bits & ~sum(ERROR_TEXT)
    if unknown:
        names.append(f"unknown error bits 0x{unknown:02x}")
    return names


class ProtocolError(Exception):
    """Bytes that are not a valid packet (not a device error: the link garbled them)."""


class ChecksumError(ProtocolError):
    pass


class LengthError(ProtocolError):
    pass


# ---------------------------------------------------------------- values
def checksum(body: bytes | bytearray) -> int:
    """The checksum of ID, LEN, INST/ERR and the parameters (the header excluded)."""
    return ~sum(body) & 0xFF


def le16(value: int) -> bytes:
    return (value & 0xFFFF).to_bytes(2, "little")


def u16(data: bytes | bytearray, offset: int = 0) -> int:
    return int.from_bytes(data[offset : offset + 2], "little")


def encode_signed(value: int, sign_bit: int) -> int:
    """Sign-magnitude: the magnitude below ``sign_bit``, the sign in it."""
    limit = (1 << sign_bit) - 1
    magnitude = abs(value)
    if magnitude > limit:
        raise ValueError(f"{value} does not fit in {sign_bit} bits and a sign")
    return magnitude | ((1 << sign_bit) if value < 0 else 0)


def decode_signed(raw: int, sign_bit: int) -> int:
    magnitude = raw & ((1 << sign_bit) - 1)
    return -magnitude if raw & (1 << sign_bit) else magnitude


# ---------------------------------------------------------------- packets
def packet(servo_id: int, code: int, params: bytes | bytearray = b"") -> bytes:
    """One packet: ``code`` is the instruction (or, from a servo, the ERR byte)."""
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo id {servo_id} is not 0..{BROADCAST_ID}")
    if len(params) + 2 > MAX_LENGTH:
        raise ValueError(f"{len(params)} parameters do not fit in one packet")
    body = bytes([servo_id, len(params) + 2, code]) + bytes(params)
    return HEADER + body + bytes([checksum(body)])


def ping(servo_id: int) -> bytes:
    return packet(servo_id, Instruction.PING)


def read(servo_id: int, address: int, length: int) -> bytes:
    return packet(servo_id, Instruction.READ, bytes([address, length]))


def write(servo_id: int, address: int, data: bytes) -> bytes:
    return packet(servo_id, Instruction.WRITE, bytes([address]) + data)


def sync_read(address: int, length: int, ids: Sequence[int]) -> bytes:
    return packet(BROADCAST_ID, Instruction.SYNC_READ, bytes([address, length, *ids]))


def sync_write(address: int, length: int, data: Mapping[int, bytes]) -> bytes:
    params = bytearray([address, length])
    for servo_id, values in data.items():
        if len(values) != length:
            raise ValueError(f"servo {servo_id}: {len(values)} bytes, expected {length}")
        params += bytes([servo_id]) + values
    return packet(BROADCAST_ID, Instruction.SYNC_WRITE, params)


def status(servo_id: int, error: int = 0, data: bytes = b"") -> bytes:
    """A servo's reply (the emulator sends these)."""
    return packet(servo_id, error, data)


@dataclass(frozen=True)
class Packet:
    """A packet as framed on the wire: ``code`` is INST (to a servo) or ERR (from one)."""

    id: int
    code: int
    params: bytes

    @property
    def error(self) -> ErrorBit:
        return ErrorBit(self.code & 0xFF)


class PacketReader:
    """Frames packets out of a byte stream: bytes before a header are skipped, a packet
    whose length or checksum is wrong is dropped (one byte at a time, so a real header
    inside it is still found) and reported by ``next()`` raising. It never holds more
    than one packet's worth of bytes past what it has framed."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self.skipped = 0  # bytes dropped while looking for a header

    def feed(self, data: bytes | bytearray) -> None:
        self._buffer += data

    @property
    def pending(self) -> int:
        return len(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()

    def next(self) -> Packet | None:
        """The next whole packet, or None until more bytes come; ``ProtocolError`` for a
        packet that is garbled (it is dropped: call again for the rest)."""
        buf = self._buffer
        start = buf.find(HEADER)
        if start < 0:  # keep a trailing FF: it may start a header
            drop = len(buf) - 1 if buf.endswith(b"\xff") else len(buf)
            self.skipped += drop
            del buf[:drop]
            return None
        # FF FF FF ID…: the header is the last two FFs (an id is never 0xFF).
        while start + 2 < len(buf) and buf[start + 2] == 0xFF:
            start += 1
        self.skipped += start
        del buf[:start]
        if len(buf) < 4:
            return None
        servo_id, length = buf[2], buf[3]
        if length < 2 or length > MAX_LENGTH:
            del buf[:2]
            raise LengthError(f"packet from id {servo_id} has length {length} (2..{MAX_LENGTH})")
        if len(buf) < length + 4:
            return None
        body = bytes(buf[2 : length + 3])
        got = buf[length + 3]
        if checksum(body) != got:
            del buf[:2]
            raise ChecksumError(
                f"packet from id {servo_id} has checksum 0x{got:02x}, "
                f"expected 0x{checksum(body):02x}"
            )
        del buf[: length + 4]
        return Packet(servo_id, body[2], body[3:])


def parse(data: bytes) -> list[Packet]:
    """Every packet in ``data`` (for tests and tools: raises on the first garbled one)."""
    reader = PacketReader()
    reader.feed(data)
    out: list[Packet] = []
    while (p := reader.next()) is not None:
        out.append(p)
    return out
