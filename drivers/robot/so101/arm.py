"""``So101Arm``: the SO-101 follower arm, six Feetech STS3215 servos on one bus.

The port is opened with ``serial.serial_for_url`` (a device path such as
``/dev/ttyACM0``, a pty, or ``socket://host:port`` for the bus emulator). At connect
the driver pings every servo and reads its model number: a servo that does not answer,
or is not an STS3215, is named (joint and id) in the error.

A poller thread owns the bus's timing: it sync-reads Present_Position, Velocity,
Load, Voltage and Temperature of all six (one 8-byte block from address 56) every
``poll_period_s`` (200 Hz by default) and hands the newest reading to the event loop
(newest wins: a busy loop skips readings, never queues them). Every reply's error
bits are checked there, in the thread: on overload, overheating, over-current, a
voltage or angle-sensor fault, or a servo silent for more than ``missed_reads_limit``
reads in a row, the thread brakes every servo at once (the same controlled stop as
``stop()``) and the driver goes to ERROR with a message naming the joint, the servo
and the fault. Writes (goals, configuration) share the bus through one lock, so a
command and a read never interleave on the wire.

Joint angles are the model's (radians, zero mid-range, ``telerobot.drivers.robot.models.so101``)
through the calibration (``calibration.So101Calibration``), loaded from
``so101_calibration`` at connect. Without one the arm connects (and can be
calibrated: ``release()``, ``raw_positions()``), but does not initialise.

A bus or servos that do not answer at start-up (an adapter still enumerating, servos
powering up, an emulator kept off the CPU on a busy machine) are tried again a few
times with a growing wait (``connect_attempts``, ``retry_delay_s``), each try said in
the log and the status message, before the arm goes to ERROR: at connect (the
handshake), and when the whole bus falls silent at once while the arm initialises
(connected again, then initialised again). One servo that stops answering is a fault
of that servo: no retry.

What is said to the servos and made of their answers (the block read and its faults,
the goal packet, the brake, the handshake, the configuration) is ``servos.py``; the
goal waiting for the poller, ``goal_slot.py``.

``stop()`` is a controlled stop, category 2: each servo's goal becomes where it can
stop from its present speed at its Acceleration setting, so it brakes without turning
back, and the servos keep torque and hold the arm there. ``disconnect()`` leaves the
torque as it is: an arm released at disconnect would fall.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Self

import numpy as np
import serial

from telerobot.drivers.base import (
    ArmSnapshot,
    DeviceContext,
    DeviceError,
    FloatArray,
    InvalidCommand,
    NotReady,
    RobotStatus,
    StopCategory,
    StopSpec,
    TelerobotError,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.bus import (
    FeetechPort,
    MissCounter,
    NoAnswer,
    open_bus,
)
from telerobot.drivers.motors.feetech.protocol import Register
from telerobot.drivers.robot.arm import ArmConfig, ModelArm
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.calibration import SERVO_IDS, STEPS_PER_RADIAN, So101Calibration
from telerobot.drivers.robot.so101.goal_slot import GoalSlot
from telerobot.drivers.robot.so101.servos import (
    GOAL_LENGTH,
    ServoStatus,
    brake_goals,
    goal_packet,
    handshake,
    hold_here,
    read_block,
    read_u16,
    torque_off_for_setup,
)
from telerobot.drivers.robot.so101.settings import (  # re-exported
    CALIBRATION_FILE,
    So101Settings,
    default_calibration_path,
)

log = logging.getLogger(__name__)

MODEL_NAME = "so101"
ARRIVED_STEPS = 6  # within this of the goal (0.5°), at rest: arrived
SETTLE_READS = 10  # at rest this many reads in a row, not at the goal: blocked, done
MIN_SPEED_STEPS = 20  # Goal_Velocity 0 would mean "as fast as it can"


@dataclass(frozen=True)
class So101Config(ArmConfig):
    """What ``So101Arm`` reads from the settings: the model (it must be so101), the
    home pose, the bus and the calibration file."""

    port: str = "/dev/ttyACM0"
    baudrate: int = ft.DEFAULT_BAUDRATE
    calibration_path: Path = field(default_factory=lambda: Path(CALIBRATION_FILE))
    reply_timeout: float = 0.03

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        arm = ArmConfig.from_settings(settings)
        if arm.robot_model != MODEL_NAME:
            raise InvalidCommand(
                f"the so101 robot driver drives the SO-101: set robot_model = 'so101' "
                f"(it is {arm.robot_model!r})"
            )
        own = So101Settings.of(settings)
        path = own.so101_calibration
        return cls(
            robot_model=arm.robot_model,
            home_pose=arm.home_pose,
            port=own.so101_port,
            baudrate=own.so101_baudrate,
            calibration_path=default_calibration_path(settings) if path is None else path,
            reply_timeout=own.so101_reply_timeout,
        )


@dataclass(frozen=True)
class _Reading:
    seq: int
    time: float  # the arm's clock
    servos: Mapping[int, ServoStatus]  # every servo, its last answer where it missed this one
    fault: TelerobotError | None = None  # what stopped the arm, once


class So101Arm(ModelArm):
    name = "so101"

    def __init__(
        self,
        port: str = "/dev/ttyACM0",
        *,
        baudrate: int = ft.DEFAULT_BAUDRATE,
        calibration: So101Calibration | None = None,
        calibration_path: Path | None = None,
        kinematics: ArmKinematics | None = None,
        clock: Clock | None = None,
        home: FloatArray | None = None,
        joint_offsets: FloatArray | None = None,
        reply_timeout: float = 0.03,
        poll_period_s: float = 0.005,
        missed_reads_limit: int = 3,
        report_period: float = 0.02,
        connect_attempts: int = 4,
        retry_delay_s: float = 0.5,
    ) -> None:
        """``calibration``: use this one (tests, tools); else it is loaded from
        ``calibration_path`` at each connect. ``reply_timeout``: how long a servo has to
        answer (it answers within a millisecond at 1 Mbaud). ``connect_attempts``: tries
        of a start-up the bus did not answer, the first wait ``retry_delay_s``, doubling."""
        if connect_attempts < 1 or not retry_delay_s >= 0:
            raise InvalidCommand("connect_attempts is at least 1 and retry_delay_s not negative")
        model = load_model(MODEL_NAME)
        super().__init__(
            model=model, kinematics=kinematics, clock=clock, home=home, joint_offsets=joint_offsets
        )
        self.port_name = port
        self.baudrate = baudrate
        self.calibration = calibration
        self.calibration_path = calibration_path
        self.reply_timeout = reply_timeout
        self.poll_period_s = poll_period_s
        self.missed_reads_limit = missed_reads_limit
        self.report_period = report_period
        self.connect_attempts = connect_attempts
        self.retry_delay_s = retry_delay_s
        # The servos brake at their Acceleration register: the model's acceleration.
        self.acceleration_register = int(
            min(254, max(1, round(float(np.min(model.amax)) * STEPS_PER_RADIAN / 100)))
        )
        self._serial: serial.Serial | None = None
        self._bus: FeetechPort | None = None
        self._poller: threading.Thread | None = None
        self._poller_stop = threading.Event()
        # A goal for the poller to put on the bus between two reads (goal_slot.py).
        self._goals = GoalSlot()
        self.goal_to_bus_s = self._goals.to_bus_s  # how long goals waited for the bus
        self._loop: asyncio.AbstractEventLoop | None = None
        self._latest: _Reading | None = None
        self._handover_pending = threading.Event()
        self._faulted = threading.Event()  # the poller stopped the arm for a fault
        self._fault: TelerobotError | None = None  # what it was, until the next connect
        self._raw = np.zeros(self.dof)
        self._velocity = np.zeros(self.dof)
        self._goal_steps: list[int] | None = None
        self._goal_seq = 0  # the reading seq when the goal was sent
        self._at_rest_reads = 0
        self._last_report = -math.inf
        self._snap: ArmSnapshot | None = None
        self.reads = 0  # sync reads done since connect
        self.reads_started = 0.0  # time.monotonic() at the first of them

    # ------------------------------------------------------------ settings
    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        config = So101Config.from_settings(settings)
        return cls(
            config.port,
            baudrate=config.baudrate,
            calibration_path=config.calibration_path,
            reply_timeout=config.reply_timeout,
            kinematics=context.kinematics(),
            clock=context.clock,
            home=config.home,
        )

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        return f"the SO-101 on {So101Settings.of(settings).so101_port}"

    @property
    def stop_spec(self) -> StopSpec:
        """A stop is one SYNC_WRITE, sent at most one bus transaction (a read waiting
        for a silent servo: the reply timeout) after ``stop()``; then every servo brakes
        at its Acceleration setting."""
        write_bytes = 4 + 2 + 2 + len(SERVO_IDS) * (1 + GOAL_LENGTH)
        decel = self.acceleration_register * 100 / STEPS_PER_RADIAN
        return StopSpec(
            category=StopCategory.CONTROLLED_HOLDING,
            decel=np.full(self.dof, decel),
            vmax=self.model.vmax.copy(),
            reaction_s=self.reply_timeout + write_bytes * 10 / self.baudrate,
            summary=(
                "every servo's goal becomes where it can stop from its present speed: the "
                "servos brake at their acceleration limit and keep torque, holding the arm "
                "where it stopped (cutting the servos' power is the category 0 stop)"
            ),
        )

    @property
    def calibrated(self) -> bool:
        return self.calibration is not None

    @property
    def _cal(self) -> So101Calibration:
        return self.calibration or So101Calibration.nominal(self.model.joint_names)

    @property
    def ids(self) -> tuple[int, ...]:
        return self._cal.ids

    @property
    def _top_speed(self) -> int:
        """The servos' Goal_Velocity of a stop or a hold: the model's fastest joint."""
        return round(float(np.max(self.model.vmax)) * STEPS_PER_RADIAN)

    # ------------------------------------------------------------ state
    def _measured_raw(self) -> FloatArray:
        return self._raw.copy()

    def snapshot(self) -> ArmSnapshot:
        snap = self._snap
        return super().snapshot() if snap is None else snap

    def servo_status(self) -> dict[str, ServoStatus]:
        """Each joint's servo as last read (position, speed, load, voltage, temperature,
        error bits, missed reads), by joint name; empty before the first read."""
        reading = self._latest
        if reading is None:
            return {}
        cal = self._cal
        return {cal.name_of(i): s for i, s in reading.servos.items()}

    def diagnostics(self) -> dict[str, Any]:
        """Each servo's state, the read rate and how long goals wait for the bus."""
        return {
            "servos": {name: asdict(s) for name, s in self.servo_status().items()},
            "read_rate_hz": self.read_rate_hz(),
            "goal_to_bus_ms": self._goals.waits_ms(),
            "counters": self.counters,
        }

    @property
    def counters(self) -> dict[str, int]:
        bus = {} if self._bus is None else dict(self._bus.counters)
        return {"reads": self.reads, **bus}

    def read_rate_hz(self) -> float:
        """Sync reads per second since connect."""
        elapsed = time.monotonic() - self.reads_started
        return 0.0 if self.reads < 2 or elapsed <= 0 else (self.reads - 1) / elapsed

    def raw_positions(self) -> list[int]:
        """Present_Position of each joint's servo as last read (for calibration)."""
        status = self.servo_status()
        if not status:
            raise NotReady("the SO-101 is not connected")
        return [status[name].position_steps for name in self.model.joint_names]

    # ------------------------------------------------------------ link
    def _require_bus(self) -> FeetechPort:
        if self._bus is None:
            raise NotReady("the SO-101 is not connected")
        return self._bus

    async def _open(self) -> None:
        await self._retrying("connecting", self._open_once)

    async def _retrying(self, what: str, attempt: Callable[[], Awaitable[None]]) -> None:
        """``attempt`` until it works, again after a growing wait while the bus does not
        answer (``NoAnswer``), at most ``connect_attempts`` times; each failure said."""
        delay = self.retry_delay_s
        for n in range(1, self.connect_attempts + 1):
            try:
                await attempt()
                return
            except NoAnswer as exc:
                if n == self.connect_attempts:
                    tries = "" if n == 1 else f" (tried {n} times)"
                    raise NoAnswer(f"{exc}{tries}") from None
                said = (
                    f"{what}: {exc}; trying again in {delay:g} s "
                    f"(attempt {n} of {self.connect_attempts})"
                )
                log.warning("the SO-101 on %r, %s", self.port_name, said)
                self._set_status(self.status, said)
                await self._close()
                await asyncio.sleep(delay)
                delay *= 2

    async def _open_once(self) -> None:
        if self.calibration_path is not None:
            self.calibration = So101Calibration.load(self.calibration_path, self.model.joint_names)
        self._serial, bus = await asyncio.to_thread(
            open_bus, self.port_name, self.baudrate, self.reply_timeout
        )
        self._bus = bus
        await asyncio.to_thread(handshake, bus, self._cal, self.port_name)
        self._loop = asyncio.get_running_loop()
        self._faulted.clear()
        self._fault = None
        self._latest = None
        self.reads = 0
        first = await asyncio.to_thread(self._read_once, bus, MissCounter(self.ids, 1), 0)
        if first.fault is not None:
            raise first.fault
        silent = [i for i, s in first.servos.items() if s.missed_reads]
        if silent:
            names = ", ".join(self._cal.label(i) for i in silent)
            raise NoAnswer(f"{names}: no answer to the first read of the arm")
        self._take(first)
        self._poller_stop.clear()
        self._poller = threading.Thread(
            target=self._poll, args=(self._bus,), name="so101-poller", daemon=True
        )
        self._poller.start()

    async def _close(self) -> None:
        self._poller_stop.set()
        self._goals.wake.set()
        if self._poller is not None:
            await asyncio.to_thread(self._poller.join, 2.0)
            self._poller = None
        if self._serial is not None:
            with contextlib.suppress(Exception):
                # In a thread: pyserial's socket:// close sleeps 0.3 s.
                await asyncio.to_thread(self._serial.close)
            self._serial = None
        self._bus = None
        self._goal_steps = None

    # ------------------------------------------------------------ the poller thread
    def _read_once(self, bus: FeetechPort, misses: MissCounter, seq: int) -> _Reading:
        """One sync read of every servo (blocking); faults stop the arm here."""
        previous = {} if self._latest is None else self._latest.servos
        servos, faults, fault_type = read_block(bus, self._cal, misses, previous, self.port_name)
        fault: TelerobotError | None = None
        if faults and not self._faulted.is_set():
            held = (
                "a stop was sent: the servos hold their last goal"
                if fault_type is NoAnswer
                else "the other servos hold it where it is"
            )
            fault = fault_type(
                "; ".join(faults) + f". The arm was stopped: {held}. "
                "Reconnect and initialise it when fixed."
            )
            self._fault = fault  # sticky: a later reading must not hide it
            self._faulted.set()
            self._brake(bus, servos)
        self.reads += 1
        if self.reads == 1:
            self.reads_started = time.monotonic()
        return _Reading(seq, self.clock.now(), servos, fault)

    def _poll(self, bus: FeetechPort) -> None:
        misses = MissCounter(self.ids, self.missed_reads_limit)
        seq = 1
        next_at = time.monotonic()
        try:
            while not self._poller_stop.is_set():
                self._goals.write(bus, self._faulted)  # a goal goes out first, at once
                if time.monotonic() < next_at:
                    self._goals.wake.wait(next_at - time.monotonic())
                    self._goals.wake.clear()
                    continue
                try:
                    reading = self._read_once(bus, misses, seq)
                except TelerobotError as exc:
                    self._stopped_by(exc, seq)
                    return
                self._latest = reading
                self._hand_over()
                seq += 1
                next_at = max(next_at + self.poll_period_s, time.monotonic())
        except TelerobotError as exc:  # a goal could not be written
            self._stopped_by(exc, seq)
        except Exception as exc:  # a bug must not end the reads unsaid: the arm faults
            log.exception("the SO-101's bus reader failed")
            self._stopped_by(DeviceError(f"the SO-101's bus reader failed: {exc}"), seq)

    def _stopped_by(self, exc: TelerobotError, seq: int) -> None:
        """The reader ends for ``exc``: no goal goes out any more, the arm faults."""
        if self._poller_stop.is_set():
            return
        self._fault = self._fault or exc
        self._faulted.set()
        self._latest = _Reading(seq, self.clock.now(), {}, exc)
        self._hand_over()

    def _hand_over(self) -> None:
        """Wake the event loop for the newest reading (once, however many came)."""
        if self._handover_pending.is_set() or self._loop is None:
            return
        self._handover_pending.set()
        with contextlib.suppress(RuntimeError):  # the loop closed: nobody is listening
            self._loop.call_soon_threadsafe(self._on_reading)

    def _brake(self, bus: FeetechPort, servos: Mapping[int, ServoStatus]) -> dict[int, int]:
        """Stop where the servos can: any goal still waiting is dropped, not sent after."""
        goals = brake_goals(servos, self.acceleration_register)
        packet = goal_packet(
            goals, dict.fromkeys(goals, self._top_speed), self.acceleration_register
        )
        self._goals.brake(bus, packet)
        return goals

    # ------------------------------------------------------------ on the event loop
    def _take(self, reading: _Reading) -> None:
        self._latest = reading
        cal = self._cal
        steps = [reading.servos[i].position_steps for i in cal.ids]
        speeds = [reading.servos[i].velocity_steps for i in cal.ids]
        self._raw = cal.to_radians(steps)
        sign = np.array([j.direction for j in cal.joints], dtype=float)
        self._velocity = sign * np.array(speeds, dtype=float) / STEPS_PER_RADIAN
        self._snap = ArmSnapshot(reading.time, self._raw + self._offsets, self._velocity.copy())

    def _on_reading(self) -> None:
        self._handover_pending.clear()
        reading = self._latest
        if reading is None:
            return
        if reading.servos:
            self._take(reading)
        fault = self._fault
        if fault is not None:  # whichever reading this is: the fault is kept apart
            if not self.status_is(RobotStatus.ERROR):
                self._goal_steps = None
                self._fail(fault)
            return
        if not self.status_is(RobotStatus.MOVING) or self._goal_steps is None:
            return
        if reading.time - self._last_report >= self.report_period:
            self._last_report = reading.time
            self._report_moved()
        if reading.seq <= self._goal_seq + 1:
            return  # not yet a reading taken after the goal went out
        cal = self._cal
        at_rest = all(reading.servos[i].velocity_steps == 0 for i in cal.ids)
        self._at_rest_reads = self._at_rest_reads + 1 if at_rest else 0
        arrived = at_rest and all(
            abs(reading.servos[i].position_steps - g) <= ARRIVED_STEPS
            for i, g in zip(cal.ids, self._goal_steps, strict=True)
        )
        if arrived or self._at_rest_reads >= SETTLE_READS:
            if not arrived:  # held short (blocked): the goal must not stay live
                here = {i: reading.servos[i].position_steps for i in cal.ids}
                speeds = dict.fromkeys(here, self._top_speed)
                self._goals.put(goal_packet(here, speeds, self.acceleration_register))
            self._goal_steps = None
            self._motion_finished()

    # ------------------------------------------------------------ initialisation
    async def initialize(self, joints: FloatArray | None = None) -> None:
        """As every arm; and if the bus did not answer while the arm initialised (every
        servo silent at once, or the bus failing: a stall, not one servo's fault), it is
        connected again and initialised again, at most ``connect_attempts`` times."""
        delay = self.retry_delay_s
        for n in range(1, self.connect_attempts + 1):
            if n > 1:
                await self.connect()  # retried while the bus does not answer, then raises
            try:
                await super().initialize(joints)
                return
            except TelerobotError as exc:
                cause = exc if isinstance(exc, NoAnswer) else self._fault
                stalled = isinstance(cause, NoAnswer) and self.status_is(RobotStatus.ERROR)
                if not stalled or n == self.connect_attempts:
                    raise
                said = (
                    f"initialising: {cause}; connecting again in {delay:g} s "
                    f"(attempt {n} of {self.connect_attempts})"
                )
                log.warning("the SO-101 on %r, %s", self.port_name, said)
                self._set_status(self.status, said)
                await asyncio.sleep(delay)
                delay *= 2

    async def _prepare(self) -> None:
        if self.calibration is None:
            where = f" ({self.calibration_path})" if self.calibration_path else ""
            raise NotReady(
                f"the SO-101 is not calibrated{where}: record its calibration, or import "
                "LeRobot's, before it can move"
            )
        bus = self._require_bus()
        await asyncio.to_thread(self._configure, bus)

    def _configure(self, bus: FeetechPort) -> None:
        """Return delay 0, acceleration and goal = present position (as last read),
        then torque on: the arm holds where it is (``servos.py``)."""
        cal = self._cal
        torque_off_for_setup(bus, cal)
        reading = self._latest
        assert reading is not None  # connect read the arm once
        here = {i: reading.servos[i].position_steps for i in cal.ids}
        hold_here(bus, cal, here, self._top_speed, self.acceleration_register)
        self._faulted.clear()
        self._fault = None

    async def release(self) -> None:
        """Torque off on every servo, so a person can move the arm (to calibrate it)."""
        if self.status_is(RobotStatus.MOVING):
            raise NotReady("the arm is moving: stop it before releasing it")
        bus = self._require_bus()
        off = dict.fromkeys(self.ids, b"\x00")
        await asyncio.to_thread(bus.transact, ft.sync_write(Register.TORQUE_ENABLE, 1, off), [])
        if not self.status_is(RobotStatus.ERROR):
            self._set_status(RobotStatus.CONNECTED, "released: torque off, initialise to move")

    async def read_homing_offsets(self) -> list[int]:
        """Each joint's servo's Homing_Offset (recorded with a calibration)."""
        bus = self._require_bus()
        raw = [
            await asyncio.to_thread(read_u16, bus, self._cal, i, Register.HOMING_OFFSET)
            for i in self.ids
        ]
        return [ft.decode_signed(r, ft.SIGN_BITS[Register.HOMING_OFFSET]) for r in raw]

    def set_calibration(self, calibration: So101Calibration, *, save: bool = True) -> None:
        """Use ``calibration`` from now on (and store it in ``calibration_path``)."""
        if self.status_is(RobotStatus.MOVING):
            raise NotReady("the calibration cannot change while the arm moves")
        if save and self.calibration_path is not None:
            calibration.save(self.calibration_path)
        self.calibration = calibration
        self._target = None
        if self._latest is not None and self._latest.servos:
            self._take(self._latest)

    # ------------------------------------------------------------ motion
    async def _send_target(self, raw_target: FloatArray) -> None:
        bus = self._require_bus()
        if self.calibration is None:
            raise NotReady("the SO-101 is not calibrated")
        cal = self.calibration
        goals = cal.to_steps(raw_target)
        # Each joint's speed in proportion to how far it goes: they arrive together.
        distance = np.abs(np.asarray(raw_target, dtype=float) - self._raw)
        longest = float(np.max(distance))
        vmax = self.model.vmax
        scale = 1.0 if longest < 1e-9 else float(np.min(vmax / np.maximum(distance, 1e-9)))
        speeds = cal.speeds_to_steps(np.minimum(vmax, distance * scale))
        packet = goal_packet(
            dict(zip(cal.ids, goals, strict=True)),
            {i: max(MIN_SPEED_STEPS, s) for i, s in zip(cal.ids, speeds, strict=True)},
            self.acceleration_register,
        )
        await self._put_on_bus(bus, packet)
        self._goal_steps = goals
        self._goal_seq = self._latest.seq if self._latest is not None else 0
        self._at_rest_reads = 0

    async def _put_on_bus(self, bus: FeetechPort, packet: bytes) -> None:
        """Hand ``packet`` to the poller, which writes it before its next read (within
        one read transaction: ``goal_to_bus_s``): taken now, as a controller takes a
        set point for its next cycle. A goal still waiting when a newer one comes is
        replaced (newest wins). Without a poller (not yet reading), written here."""
        if self._fault is not None:
            raise self._fault
        poller = self._poller
        if poller is None or not poller.is_alive():
            raise DeviceError("the SO-101's bus reader is not running: reconnect the arm")
        self._goals.put(packet)

    async def _halt(self) -> None:
        bus = self._require_bus()
        reading = self._latest
        if reading is None or not reading.servos:
            return
        goals = await asyncio.to_thread(self._brake, bus, reading.servos)
        self._goal_steps = [goals[i] for i in self.ids]
        self._goal_seq = reading.seq
        self._at_rest_reads = 0
