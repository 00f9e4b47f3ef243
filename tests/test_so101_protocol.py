"""The Feetech byte protocol (telerobot.drivers.motors.feetech.protocol) and the bus emulator's
answers to it, without any I/O."""

from __future__ import annotations

import pytest

from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.protocol import ErrorBit, Instruction, Register
from telerobot.drivers.robot.so101.emulator import FeetechBusEmulator


def test_packets_are_the_documented_bytes() -> None:
    # PING servo 1: FF FF 01 02 01 ~(1+2+1)
    assert ft.ping(1) == bytes([0xFF, 0xFF, 0x01, 0x02, 0x01, 0xFB])
    # READ servo 1, 2 bytes from 56: LEN = 4
    assert ft.read(1, 56, 2) == bytes([0xFF, 0xFF, 1, 4, 2, 56, 2, ~(1 + 4 + 2 + 56 + 2) & 0xFF])
    # WRITE goal 2048 (little-endian) to servo 3
    assert ft.write(3, 42, ft.le16(2048))[2:8] == bytes([3, 5, 3, 42, 0x00, 0x08])
    sr = ft.sync_read(56, 8, [1, 2, 3])
    assert sr[2:5] == bytes([ft.BROADCAST_ID, 7, Instruction.SYNC_READ])
    assert sr[5:-1] == bytes([56, 8, 1, 2, 3])
    sw = ft.sync_write(42, 2, {1: ft.le16(100), 2: ft.le16(4000)})
    assert sw[3] == 2 + 2 * 3 + 2 and sw[5:-1] == bytes([42, 2, 1, 100, 0, 2, 0xA0, 0x0F])
    with pytest.raises(ValueError, match="expected 2"):
        ft.sync_write(42, 2, {1: b"\x00"})
    with pytest.raises(ValueError, match="servo id"):
        ft.ping(300)


def test_status_packets_round_trip() -> None:
    data = ft.status(2, ErrorBit.OVERLOAD | ErrorBit.OVERHEAT, bytes([1, 2, 3]))
    (p,) = ft.parse(data)
    assert (p.id, p.params) == (2, bytes([1, 2, 3]))
    assert p.error == ErrorBit.OVERLOAD | ErrorBit.OVERHEAT
    assert ft.error_names(p.code) == ["overheating", "overload"]
    assert ft.error_names(0x50) == ["unknown error bits 0x50"]


def test_sign_magnitude() -> None:
    assert ft.encode_signed(-5, 15) == 0x8005
    assert ft.decode_signed(0x8005, 15) == -5
    assert ft.decode_signed(ft.encode_signed(-1000, 10), 10) == -1000
    assert ft.decode_signed(0x0400 | 7, 10) == -7  # Present_Load's sign is bit 10
    assert ft.encode_signed(300, 15) == 300
    with pytest.raises(ValueError, match="does not fit"):
        ft.encode_signed(2048, 11)


def test_garbage_before_a_header_is_skipped() -> None:
    reader = ft.PacketReader()
    good = ft.status(4, 0, b"\x10\x20")
    reader.feed(b"\x00\x13\xfe\xff" + good[:5])  # junk, a lone FF, half a packet
    assert reader.next() is None
    reader.feed(good[5:] + b"\xff")
    p = reader.next()
    assert p is not None and (p.id, p.params) == (4, b"\x10\x20")
    assert reader.skipped == 4 and reader.pending == 1  # the trailing FF may start a header
    # Three FFs: the header is the last two.
    assert ft.parse(b"\xff" + ft.status(5)) == [ft.Packet(5, 0, b"")]


def test_bad_checksum_is_reported_and_the_next_packet_still_found() -> None:
    bad = bytearray(ft.status(1, 0, b"\x01\x02"))
    bad[-1] ^= 0x55
    reader = ft.PacketReader()
    reader.feed(bytes(bad) + ft.status(2, 0, b"\x03"))
    with pytest.raises(ft.ChecksumError, match="packet from id 1 has checksum"):
        reader.next()
    p = reader.next()
    assert p is not None and p.id == 2


def test_a_length_past_the_limit_is_refused_at_once() -> None:
    """LEN above MAX_LENGTH (250) is garbage: the reader does not wait for 255 bytes."""
    reader = ft.PacketReader()
    reader.feed(bytes([0xFF, 0xFF, 1, ft.MAX_LENGTH + 1, 0]) + ft.status(3))
    with pytest.raises(ft.LengthError, match="length 251"):
        reader.next()
    p = reader.next()
    assert p is not None and p.id == 3
    reader.feed(bytes([0xFF, 0xFF, 1, 1]))  # below the minimum (2)
    with pytest.raises(ft.LengthError):
        reader.next()
    # The largest legal packet is framed.
    ok = ft.packet(1, 0, bytes(ft.MAX_LENGTH - 2))
    assert ft.parse(ok)[0].params == bytes(ft.MAX_LENGTH - 2)
    with pytest.raises(ValueError, match="do not fit"):
        ft.packet(1, 0, bytes(ft.MAX_LENGTH - 1))


# ---------------------------------------------------------------- the emulator's answers
def test_emulator_answers_ping_read_and_sync_read() -> None:
    bus = FeetechBusEmulator(start={1: 1000.0, 2: 3000.0})
    (p,) = ft.parse(bus.receive(ft.ping(2), 0.0))
    assert (p.id, p.code, p.params) == (2, 0, b"")
    (m,) = ft.parse(bus.receive(ft.read(2, Register.MODEL_NUMBER, 2), 0.0))
    assert ft.u16(m.params) == ft.STS3215_MODEL
    replies = ft.parse(bus.receive(ft.sync_read(56, 8, [2, 1, 6]), 0.0))
    assert [r.id for r in replies] == [2, 1, 6]  # in the order asked
    assert [ft.u16(r.params) for r in replies] == [3000, 1000, 2048]
    assert replies[0].params[6] == 120 and replies[0].params[7] == 30  # 12.0 V, 30 °C
    assert bus.receive(ft.ping(9), 0.0) == b""  # no such servo
    assert bus.receive(ft.packet(ft.BROADCAST_ID, Instruction.PING), 0.0) == b""


def test_emulated_servo_moves_to_its_goal_at_its_speed() -> None:
    bus = FeetechBusEmulator(start={1: 1000.0})
    goal = bytes([50]) + ft.le16(2000) + ft.le16(0) + ft.le16(1000)  # acc 5000 steps/s²
    assert bus.receive(ft.sync_write(41, 7, {1: goal}), 0.0) == b""  # no reply
    bus.receive(ft.write(1, Register.TORQUE_ENABLE, b"\x01"), 0.0)
    bus.advance(0.5)
    servo = bus.servos[1]
    assert 1000 < servo.position < 2000 and servo.velocity == pytest.approx(1000)
    bus.advance(2.0)
    assert servo.position == 2000 and servo.velocity == 0
    servo.refresh()
    assert servo.memory[Register.MOVING] == 0


def test_emulator_faults() -> None:
    bus = FeetechBusEmulator()
    bus.servos[3].mute = True
    replies = ft.parse(bus.receive(ft.sync_read(56, 8, [1, 2, 3, 4]), 0.0))
    assert [r.id for r in replies] == [1, 2, 4]
    bus.servos[2].error = ErrorBit.OVERLOAD
    (p,) = ft.parse(bus.receive(ft.ping(2), 0.0))
    assert p.error == ErrorBit.OVERLOAD
    bus.receive(ft.write(2, Register.TORQUE_ENABLE, b"\x01"), 0.0)
    assert not bus.servos[2].torque  # overloaded: it unloads
    bus.garbage = b"\x00\x01\xff"
    reply = bus.receive(ft.ping(1), 0.0)
    assert reply.startswith(b"\x00\x01\xff") and ft.parse(reply)[0].id == 1
    corrupt = bytearray(ft.ping(1))
    corrupt[-1] ^= 1
    assert bus.receive(bytes(corrupt), 0.0) == b"" and bus.rejected == 1


def test_locked_eprom_ignores_writes() -> None:
    bus = FeetechBusEmulator()
    bus.receive(ft.write(1, Register.LOCK, b"\x01"), 0.0)
    bus.receive(ft.write(1, Register.RETURN_DELAY_TIME, b"\x00"), 0.0)
    assert bus.servos[1].memory[Register.RETURN_DELAY_TIME] == 250
    bus.receive(ft.write(1, Register.LOCK, b"\x00"), 0.0)
    bus.receive(ft.write(1, Register.RETURN_DELAY_TIME, b"\x00"), 0.0)
    assert bus.servos[1].memory[Register.RETURN_DELAY_TIME] == 0
