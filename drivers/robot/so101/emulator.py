"""An emulated Feetech bus of STS3215 servos (the SO-101's six by default) that
answers the same bytes as the real ones, on a pseudo-terminal or a TCP port.

``FeetechBusEmulator`` is the servos: register memory per servo (the STS3215 control
table), and a motion model: with torque on, a servo moves toward Goal_Position at
most at its goal velocity, accelerating and braking at its Acceleration register, as
the servo's own profile does; Present_Position/Velocity/Load/Voltage/Temperature are
refreshed when read. ``BusLink`` runs it on a real pty or socket in a thread of its
own, so a driver under test goes through real file descriptors (``serial_for_url``
opens the pty's path or ``socket://host:port``), as ``val_emulator`` does for the VAL
controller.

Faults for the tests: a servo that stops answering (``mute``), error bits in its
replies (``error``: overload also unloads the servo's torque, as the STS3215 does),
garbage bytes before the next reply (``garbage``), the temperature it reports.

``python -m telerobot.drivers.robot.so101.emulator [--tcp PORT]`` runs it standalone and prints
the address to give the driver (``so101_port``).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

from telerobot.drivers.emulator_link import EmulatorLink
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.protocol import ErrorBit, Instruction, Register

log = logging.getLogger(__name__)

SO101_IDS = (1, 2, 3, 4, 5, 6)
MAX_SPEED_STEPS = 3400.0  # steps/s: about the STS3215's unloaded speed at 12 V
MAX_ACCEL_STEPS = 25_400.0  # steps/s² when Acceleration is 0 (the register's top, 254)
_SUBSTEP_S = 0.001  # the motion model integrates in steps of at most this


@dataclass
class EmulatedServo:
    """One STS3215: its registers and where its output shaft is (``position``, steps,
    before the homing offset; set it with torque off to move the arm "by hand")."""

    id: int
    position: float = 2048.0
    velocity: float = 0.0  # steps/s
    voltage_v: float = 12.0
    temperature_c: float = 30.0
    error: int = 0  # bits of ErrorBit in every reply
    mute: bool = False  # answers nothing
    blocked: bool = False  # something holds the shaft: it does not turn
    model: int = ft.STS3215_MODEL
    memory: bytearray = field(default_factory=lambda: bytearray(256))

    def __post_init__(self) -> None:
        m = self.memory
        m[Register.MODEL_NUMBER : Register.MODEL_NUMBER + 2] = ft.le16(self.model)
        m[Register.ID] = self.id
        m[Register.RETURN_DELAY_TIME] = 250
        m[Register.MAX_POSITION_LIMIT : Register.MAX_POSITION_LIMIT + 2] = ft.le16(4095)
        self.set_u16(Register.GOAL_POSITION, self.present_position)
        self.refresh()

    # ---------------------------------------------------------- registers
    def u16(self, address: int) -> int:
        return ft.u16(self.memory, address)

    def set_u16(self, address: int, value: int) -> None:
        self.memory[address : address + 2] = ft.le16(value)

    def signed(self, register: Register) -> int:
        return ft.decode_signed(self.u16(register), ft.SIGN_BITS[register])

    @property
    def torque(self) -> bool:
        return bool(self.memory[Register.TORQUE_ENABLE])

    @property
    def homing_offset(self) -> int:
        return self.signed(Register.HOMING_OFFSET)

    @property
    def present_position(self) -> int:
        return (round(self.position) - self.homing_offset) % ft.STEPS_PER_TURN

    def write(self, address: int, data: bytes) -> None:
        if address < Register.TORQUE_ENABLE and self.memory[Register.LOCK]:
            return  # EPROM is locked: the servo ignores the write
        if address <= Register.ID < address + len(data):
            log.warning("servo %d: the emulator does not change servo ids", self.id)
            return
        self.memory[address : address + len(data)] = data
        if self.error & ErrorBit.OVERLOAD:
            self.memory[Register.TORQUE_ENABLE] = 0  # unloaded until the fault clears
        if not self.torque:
            self.velocity = 0.0

    def refresh(self) -> None:
        """Present_* registers from the motion state."""
        m = self.memory
        self.set_u16(Register.PRESENT_POSITION, self.present_position)
        speed = round(self.velocity)
        self.set_u16(Register.PRESENT_VELOCITY, ft.encode_signed(speed, 15))
        load = round(min(1000.0, 80.0 + 0.1 * abs(self.velocity))) if self.torque else 0
        self.set_u16(Register.PRESENT_LOAD, ft.encode_signed(-load if speed < 0 else load, 10))
        m[Register.PRESENT_VOLTAGE] = round(self.voltage_v * 10) & 0xFF
        m[Register.PRESENT_TEMPERATURE] = round(self.temperature_c) & 0xFF
        m[Register.STATUS] = self.error & 0xFF
        m[Register.MOVING] = int(speed != 0)

    # ---------------------------------------------------------- motion
    def step(self, dt: float) -> None:
        if not self.torque or self.blocked:
            self.velocity = 0.0
            return
        goal = ft.decode_signed(self.u16(Register.GOAL_POSITION), 15) + self.homing_offset
        vmax = abs(self.signed(Register.GOAL_VELOCITY)) or MAX_SPEED_STEPS
        accel = self.memory[Register.ACCELERATION] * 100.0 or MAX_ACCEL_STEPS
        remaining = dt
        while remaining > 1e-12:
            h = min(_SUBSTEP_S, remaining)
            remaining -= h
            distance = goal - self.position
            if abs(distance) < 0.5 and abs(self.velocity) <= accel * h:
                self.position, self.velocity = float(goal), 0.0
                continue
            # The fastest speed from which the servo still stops at the goal.
            wanted = math.copysign(min(vmax, math.sqrt(2.0 * accel * abs(distance))), distance)
            dv = max(-accel * h, min(accel * h, wanted - self.velocity))
            self.velocity += dv
            self.position += self.velocity * h
            if (goal - self.position) * distance < 0 and abs(self.velocity) <= accel * h * 2:
                self.position, self.velocity = float(goal), 0.0  # arrived this substep


class FeetechBusEmulator:
    """Servos on one bus, fed the bytes the driver sends, with the time they arrive."""

    def __init__(
        self,
        ids: Iterable[int] = SO101_IDS,
        *,
        start: Mapping[int, float] | None = None,
        models: Mapping[int, int] | None = None,
    ) -> None:
        start = start or {}
        models = models or {}
        self.servos: dict[int, EmulatedServo] = {
            i: EmulatedServo(
                i, position=start.get(i, 2048.0), model=models.get(i, ft.STS3215_MODEL)
            )
            for i in ids
        }
        self.garbage = b""  # sent before the next reply, once
        self.sync_reads = 0
        self.sync_writes = 0
        self.rejected = 0  # instruction packets with a bad length or checksum
        self._reader = ft.PacketReader()
        self._time: float | None = None

    def advance(self, now: float) -> None:
        if self._time is not None and now > self._time:
            for servo in self.servos.values():
                servo.step(now - self._time)
        self._time = now if self._time is None else max(self._time, now)

    def receive(self, data: bytes, now: float) -> bytes:
        """The bytes the bus sends back for ``data``."""
        self.advance(now)
        self._reader.feed(data)
        out = bytearray()
        while True:
            try:
                p = self._reader.next()
            except ft.ProtocolError:
                self.rejected += 1
                continue
            if p is None:
                break
            out += self._execute(p)
        if out and self.garbage:
            out[:0], self.garbage = self.garbage, b""
        return bytes(out)

    def _reply(self, servo: EmulatedServo, data: bytes = b"") -> bytes:
        if servo.mute:
            return b""
        return ft.status(servo.id, servo.error & 0x7F, data)

    def _read(self, servo: EmulatedServo, address: int, length: int) -> bytes:
        servo.refresh()
        return self._reply(servo, bytes(servo.memory[address : address + length]))

    def _execute(self, p: ft.Packet) -> bytes:
        params = p.params
        if p.code == Instruction.SYNC_READ and p.id == ft.BROADCAST_ID and len(params) >= 2:
            self.sync_reads += 1
            address, length = params[0], params[1]
            return b"".join(
                self._read(self.servos[i], address, length) for i in params[2:] if i in self.servos
            )
        if p.code == Instruction.SYNC_WRITE and p.id == ft.BROADCAST_ID and len(params) >= 2:
            self.sync_writes += 1
            address, length = params[0], params[1]
            for k in range(2, len(params) - length, length + 1):
                servo = self.servos.get(params[k])
                if servo is not None and not servo.mute:
                    servo.write(address, params[k + 1 : k + 1 + length])
            return b""
        targets = list(self.servos.values()) if p.id == ft.BROADCAST_ID else []
        if p.id in self.servos:
            targets = [self.servos[p.id]]
        out = b""
        for servo in targets:
            if servo.mute:
                continue
            reply = b""
            if p.code == Instruction.PING:
                reply = self._reply(servo)
            elif p.code == Instruction.READ and len(params) == 2:
                reply = self._read(servo, params[0], params[1])
            elif p.code == Instruction.WRITE and len(params) >= 2:
                servo.write(params[0], params[1:])
                reply = self._reply(servo)
            if p.id != ft.BROADCAST_ID:  # nobody answers a broadcast
                out += reply
        return out


class BusLink(EmulatorLink):
    """Runs a bus emulator on a pseudo-terminal or a TCP port
    (``telerobot.drivers.emulator_link``): packets in, the servos' replies out."""

    thread_name = "feetech-emulator"

    def __init__(
        self, bus: FeetechBusEmulator, clock: Callable[[], float] = time.monotonic
    ) -> None:
        super().__init__(clock)
        self.bus = bus
        self._lock = threading.Lock()  # the bus is also read by tests

    @classmethod
    def on_pty(cls, bus: FeetechBusEmulator) -> BusLink:
        return cls(bus)._open_pty()

    @classmethod
    def on_tcp(cls, bus: FeetechBusEmulator, host: str = "127.0.0.1", port: int = 0) -> BusLink:
        return cls(bus)._open_tcp(host, port)

    def servo(self, servo_id: int) -> EmulatedServo:
        """A servo, its motion brought up to now (to read or change between packets)."""
        with self._lock:
            self.bus.advance(self.clock())
            return self.bus.servos[servo_id]

    def _received(self, data: bytes) -> bytes:
        with self._lock:
            try:
                return self.bus.receive(data, self.clock())
            except Exception:  # a bug here must not silence the bus: log it, go on
                log.exception("the emulator failed on %r", data[:64])
                return b""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="An emulated SO-101 Feetech servo bus.")
    parser.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP (default: a pty)")
    parser.add_argument("--host", default="127.0.0.1")
    args = parser.parse_args(argv)
    bus = FeetechBusEmulator()
    link = BusLink.on_pty(bus) if args.tcp is None else BusLink.on_tcp(bus, args.host, args.tcp)
    with link:
        print(f"SO-101 bus emulator (servos {', '.join(map(str, bus.servos))}) on {link.url}")
        print(
            "run the server with TELEROBOT_ROBOT=so101 TELEROBOT_ROBOT_MODEL=so101 "
            f"TELEROBOT_SO101_PORT={link.url}"
        )
        with contextlib.suppress(KeyboardInterrupt):
            while True:
                time.sleep(3600)


if __name__ == "__main__":
    main()
