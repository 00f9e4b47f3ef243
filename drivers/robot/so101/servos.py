"""What the SO-101's driver (arm.py) says to its six servos on the bus and makes of
their answers: the one block read of all six and the faults in it, the goal packet
and the brake's goals, the handshake at connect (their homing offsets) and their
configuration before the arm moves.

Apart from ``So101Arm`` because these are the servos' protocol, blocking calls on a
``FeetechPort`` with no state of their own: when they run (the poller thread, a
thread at connect), what a fault does to the arm and the goal's hand-over to the
poller are the arm's."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace

from telerobot.drivers.base import DeviceError, TelerobotError
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.bus import FeetechPort, MissCounter, NoAnswer, identify_servos
from telerobot.drivers.motors.feetech.protocol import ErrorBit, Register
from telerobot.drivers.robot.so101.calibration import So101Calibration

# One read of all six: Present_Position, Present_Velocity, Present_Load (2 bytes
# each), Present_Voltage, Present_Temperature (1 byte each), from address 56.
BLOCK_ADDRESS = Register.PRESENT_POSITION
BLOCK_LENGTH = 8
# Written per servo with each goal: Acceleration, Goal_Position, Goal_Time, Goal_Velocity.
GOAL_ADDRESS = Register.ACCELERATION
GOAL_LENGTH = 7
FAULTS = ErrorBit.VOLTAGE | ErrorBit.ANGLE_SENSOR | ErrorBit.OVERHEAT | ErrorBit.OVERCURRENT
FAULTS |= ErrorBit.OVERLOAD
ADVICE: Mapping[ErrorBit, str] = {
    ErrorBit.OVERLOAD: "free what blocks it or lighten its load",
    ErrorBit.OVERHEAT: "let it cool down",
    ErrorBit.OVERCURRENT: "free what blocks it and check its wiring",
    ErrorBit.VOLTAGE: "check the power supply (the STS3215 takes 6-12.6 V)",
    ErrorBit.ANGLE_SENSOR: "the servo's position sensor failed: replace the servo",
}


@dataclass(frozen=True)
class ServoStatus:
    """One servo as last read (what the server shows per joint)."""

    id: int
    position_steps: int
    velocity_steps: int  # steps/s
    load_percent: float  # of the servo's maximum torque, signed
    voltage_v: float
    temperature_c: float
    errors: tuple[str, ...]  # the error bits of its last reply, in words
    missed_reads: int  # reads in a row it did not answer


def read_block(
    bus: FeetechPort,
    cal: So101Calibration,
    misses: MissCounter,
    previous: Mapping[int, ServoStatus],
    port_name: str,
) -> tuple[dict[int, ServoStatus], list[str], type[TelerobotError]]:
    """One sync read of every servo (blocking): each servo's status (its ``previous``
    one where it did not answer), the faults read in it, in words, and the error they
    make (NoAnswer when the whole bus fell silent, else DeviceError)."""
    ids = list(cal.ids)
    replies = bus.transact(ft.sync_read(BLOCK_ADDRESS, BLOCK_LENGTH, ids), ids)
    lost = misses.update([i for i, p in replies.items() if len(p.params) == BLOCK_LENGTH])
    servos: dict[int, ServoStatus] = {}
    faults: list[str] = []
    for i in ids:
        p = replies.get(i)
        if p is None or len(p.params) != BLOCK_LENGTH:
            old = previous.get(i) or ServoStatus(i, 0, 0, 0.0, 0.0, 0.0, (), 0)
            servos[i] = replace(old, missed_reads=misses.missed[i])
            continue
        d = p.params
        s = ServoStatus(
            id=i,
            position_steps=ft.decode_signed(ft.u16(d, 0), 15),
            velocity_steps=ft.decode_signed(ft.u16(d, 2), 15),
            load_percent=ft.decode_signed(ft.u16(d, 4), 10) / 10.0,
            voltage_v=d[6] / 10.0,
            temperature_c=float(d[7]),
            errors=tuple(ft.error_names(p.code)),
            missed_reads=0,
        )
        servos[i] = s
        bad = ErrorBit(p.code & FAULTS)
        if bad:
            advice = "; ".join(text for bit, text in ADVICE.items() if bad & bit)
            faults.append(
                f"{cal.label(i)} reports {' and '.join(ft.error_names(bad))} "
                f"({s.temperature_c:.0f} °C, {s.voltage_v:.1f} V, load {s.load_percent:.0f} %)"
                f": {advice}"
            )
    fault_type: type[TelerobotError] = DeviceError
    if lost and len(lost) == len(ids):  # the bus fell silent, not one servo
        fault_type = NoAnswer
        faults.append(
            f"all {len(ids)} servos stopped answering on {port_name!r} "
            f"({misses.missed[lost[0]]} reads in a row): the bus fell silent (its "
            "adapter, its cable, the servos' power, or an emulator kept off the CPU)"
        )
    elif lost:
        faults += [
            f"{cal.label(i)} stopped answering on {port_name!r} "
            f"({misses.missed[i]} reads in a row): check its cable and power"
            for i in lost
        ]
    return servos, faults, fault_type


def goal_packet(goals: Mapping[int, int], speeds: Mapping[int, int], acceleration: int) -> bytes:
    """One SYNC_WRITE of each servo's goal (steps) at its speed (steps/s)."""
    data = {
        i: bytes([acceleration])
        + ft.le16(ft.encode_signed(goal, 15))
        + ft.le16(0)
        + ft.le16(speeds[i])
        for i, goal in goals.items()
    }
    return ft.sync_write(GOAL_ADDRESS, GOAL_LENGTH, data)


def brake_goals(servos: Mapping[int, ServoStatus], acceleration: int) -> dict[int, int]:
    """Where each servo stops from its present speed at its acceleration."""
    a = acceleration * 100.0
    return {
        i: int(
            min(
                ft.STEPS_PER_TURN - 1,
                max(
                    0,
                    round(
                        s.position_steps
                        + math.copysign(s.velocity_steps**2 / (2 * a), s.velocity_steps)
                    ),
                ),
            )
        )
        for i, s in servos.items()
    }


def read_u16(bus: FeetechPort, cal: So101Calibration, servo_id: int, address: int) -> int:
    reply = bus.transact(ft.read(servo_id, address, 2), [servo_id])
    if servo_id not in reply or len(reply[servo_id].params) != 2:
        raise NoAnswer(f"{cal.label(servo_id)} did not answer a read of {address}")
    return ft.u16(reply[servo_id].params)


def write_checked(
    bus: FeetechPort, cal: So101Calibration, servo_id: int, address: int, data: bytes
) -> None:
    reply = bus.transact(ft.write(servo_id, address, data), [servo_id])
    if servo_id not in reply:
        raise NoAnswer(f"{cal.label(servo_id)} did not confirm a write to {address}")


def handshake(bus: FeetechPort, cal: So101Calibration, port_name: str) -> None:
    """The servos identified, then the homing offsets checked (blocking: a thread)."""
    identify_servos(bus, cal, port_name)
    for joint in cal.joints:
        if joint.homing_offset is not None:
            offset = read_u16(bus, cal, joint.id, Register.HOMING_OFFSET)
            held = ft.decode_signed(offset, ft.SIGN_BITS[Register.HOMING_OFFSET])
            if held != joint.homing_offset:
                raise DeviceError(
                    f"{cal.label(joint.id)} holds Homing_Offset {held}, but the "
                    f"calibration was recorded with {joint.homing_offset}: "
                    "record the calibration again"
                )


def torque_off_for_setup(bus: FeetechPort, cal: So101Calibration) -> None:
    """Torque off, and each servo's return delay 0 (EPROM, written only if it differs):
    the first half of the configuration before the arm moves."""
    ids = list(cal.ids)
    bus.transact(ft.sync_write(Register.TORQUE_ENABLE, 1, dict.fromkeys(ids, b"\x00")), [])
    for i in ids:
        reply = bus.transact(ft.read(i, Register.RETURN_DELAY_TIME, 1), [i])
        if i not in reply:
            raise NoAnswer(f"{cal.label(i)} did not answer while being configured")
        if reply[i].params != b"\x00":
            write_checked(bus, cal, i, Register.LOCK, b"\x00")
            write_checked(bus, cal, i, Register.RETURN_DELAY_TIME, b"\x00")


def hold_here(
    bus: FeetechPort, cal: So101Calibration, here: Mapping[int, int], top: int, acceleration: int
) -> None:
    """The second half: acceleration and goal = ``here`` (each servo's present position),
    then torque on and the EPROM locked: the arm holds where it is."""
    ids = list(cal.ids)
    bus.transact(goal_packet(here, dict.fromkeys(ids, top), acceleration), [])
    on = dict.fromkeys(ids, b"\x01")
    bus.transact(ft.sync_write(Register.TORQUE_ENABLE, 1, on), [])
    bus.transact(ft.sync_write(Register.LOCK, 1, on), [])
