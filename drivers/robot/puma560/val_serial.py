"""``ValSerialPuma``: a PUMA 560 on a Unimation controller over RS-232.

As in the thesis (§4.3.1), initialisation uploads a small resident VAL program
(``TRINC``) that reads joint increments from the terminal and executes them; the
driver sends increments and reads positions back from the controller's replies.
The exchange is in docs/val-protocol.md and in ``val_protocol``.

The port is opened with ``serial.serial_for_url``, so a device path, a
pseudo-terminal, ``socket://host:port`` (an emulator) or ``loop://`` all work.
A reader thread turns bytes into lines; everything else runs on the event loop.
A timeout, a garbled or unexpected reply, or a lost link puts the driver into
ERROR with a message that says what happened; ``connect()`` again recovers.

Targets coalesce: while a move is on the wire, newer targets replace each other
and the next increment sent is (newest target − reported position), so a slow
serial link never replays stale commands.

``stop()`` does not wait for the increment on the wire to end: it sends ``ABORT``
at once (VAL's monitor takes it even while ``TRINC`` is inside ``MOVE``), the
controller's drives bring the arm to rest at their deceleration limit and show the
monitor prompt, and the driver starts ``TRINC`` again and reads where the arm
stopped. A category 2 stop (IEC 60204-1): arm power stays on and the servos hold
the arm; the controller's hardware e-stop remains the category 0 stop.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Self

import numpy as np
import serial

from telerobot.drivers.base import (
    DeviceContext,
    DeviceError,
    FloatArray,
    SerialSettings,
    StopCategory,
    StopSpec,
    TelerobotError,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.robot.motion import PUMA_STOP_DECEL, PUMA_VMAX
from telerobot.drivers.robot.puma560 import val_protocol as vp
from telerobot.drivers.robot.puma560.arm import PumaArm, PumaConfig
from telerobot.drivers.robot.puma560.settings import ValSerialSettings

log = logging.getLogger(__name__)

_MIN_INCREMENT_DEG = 0.00005  # below VAL's 4-decimal resolution: nothing to send
# VAL sends the joint servos a new set point every 28 ms: an ABORT acts within one.
VAL_TRAJECTORY_CYCLE_S = 0.028


@dataclass(frozen=True)
class ValSerialConfig(PumaConfig):
    """What ``ValSerialPuma`` reads from the settings: the home pose and the link."""

    serial: SerialSettings = field(default_factory=SerialSettings)

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        own = ValSerialSettings.of(settings)
        return cls(
            home_pose=PumaConfig.from_settings(settings).home_pose,
            serial=SerialSettings(
                port=own.serial_port,
                baudrate=own.serial_baudrate,
                reply_timeout=own.serial_reply_timeout,
            ),
        )


class ValSerialPuma(PumaArm):
    name = "val-puma560"

    def __init__(
        self,
        settings: SerialSettings | None = None,
        *,
        kinematics: ArmKinematics | None = None,
        clock: Clock | None = None,
        home: FloatArray | None = None,
        joint_offsets: FloatArray | None = None,
        stop_decel: FloatArray = PUMA_STOP_DECEL,
    ) -> None:
        """``stop_decel``: how fast the controller brakes each joint on ``ABORT``
        (rad/s²), as measured on the arm; it is what the server states, not a setting
        sent to the controller."""
        super().__init__(kinematics=kinematics, clock=clock, home=home, joint_offsets=joint_offsets)
        self._stop_decel = np.asarray(stop_decel, dtype=float).copy()
        self._settings = settings or SerialSettings()
        self._serial: serial.Serial | None = None
        self._reader: threading.Thread | None = None
        self._reader_stop = threading.Event()
        self._replies: asyncio.Queue[vp.Reply | TelerobotError] = asyncio.Queue()
        self._raw = np.zeros(6)
        self._raw_target: FloatArray | None = None
        self._pump: asyncio.Task[None] | None = None
        self._wake = asyncio.Event()
        self._seq = 0
        self._last_sent = ""
        self._send_lock = asyncio.Lock()  # one line at a time, whole, in order
        self._write_lock = threading.Lock()
        self._on_wire: int | None = None  # seq of the increment sent and not yet DONE
        self._aborting = False  # ABORT sent; its prompt not yet handled
        self._abort_prompt = False  # …and its prompt has arrived

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        config = ValSerialConfig.from_settings(settings)
        return cls(
            config.serial, kinematics=context.kinematics(), clock=context.clock, home=config.home
        )

    @classmethod
    def describe(cls, settings: Mapping[str, Any]) -> str:
        return f"the {settings['robot']} robot on {ValSerialSettings.of(settings).serial_port}"

    @property
    def stop_spec(self) -> StopSpec:
        """``ABORT`` is sent within one line's time (a line being written is finished
        first: the longest increment line plus ``ABORT`` at the baud rate) and acts
        within one VAL trajectory cycle; then the controller's drives brake."""
        s = self._settings
        bits = 1 + s.bytesize + (0 if s.parity == "N" else 1) + s.stopbits
        longest = len(vp.increment_line(10**9, [-999.9999] * 6)) + len("\rABORT\r")
        return StopSpec(
            category=StopCategory.CONTROLLED_HOLDING,
            decel=self._stop_decel.copy(),
            vmax=PUMA_VMAX.copy(),
            reaction_s=longest * bits / s.baudrate + VAL_TRAJECTORY_CYCLE_S,
            summary=(
                "ABORT is sent at once: the controller's drives brake every joint together "
                "at their limit and keep arm power on, holding the arm where it stopped "
                "(the controller's hardware e-stop is the category 0 stop)"
            ),
        )

    # ------------------------------------------------------------ settings
    @property
    def serial_settings(self) -> SerialSettings:
        return self._settings

    @serial_settings.setter
    def serial_settings(self, settings: SerialSettings) -> None:
        """Takes effect at the next ``connect()``."""
        self._settings = replace(settings)

    def _measured_raw(self) -> FloatArray:
        return self._raw.copy()

    # ------------------------------------------------------------ link
    async def _open(self) -> None:
        s = self._settings
        try:
            self._serial = await asyncio.to_thread(
                serial.serial_for_url,
                s.port,
                baudrate=s.baudrate,
                bytesize=s.bytesize,
                parity=s.parity,
                stopbits=s.stopbits,
                timeout=0.05,
                write_timeout=s.reply_timeout,
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open serial port {s.port!r}: {exc}") from None
        self._replies = asyncio.Queue()
        self._reader_stop.clear()
        loop = asyncio.get_running_loop()
        self._reader = threading.Thread(
            target=self._read_lines,
            args=(self._serial, loop),
            name="val-serial-reader",
            daemon=True,
        )
        self._reader.start()
        # ABORT returns any controller, even one still running TRINC from an earlier
        # session, to the monitor prompt.
        await self._request("ABORT", vp.Text(vp.PROMPT))

    async def _close(self) -> None:
        if self._pump is not None:
            self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
            self._pump = None
        self._reader_stop.set()
        if self._reader is not None:
            await asyncio.to_thread(self._reader.join, 1.0)
            self._reader = None
        if self._serial is not None:
            with contextlib.suppress(Exception):
                self._serial.close()
            self._serial = None
        self._raw_target = None
        self._reset_abort()

    def _reset_abort(self) -> None:
        self._on_wire = None
        self._aborting = self._abort_prompt = False

    def _read_lines(self, port: serial.Serial, loop: asyncio.AbstractEventLoop) -> None:
        buffer = b""
        while not self._reader_stop.is_set():
            try:
                chunk = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not self._reader_stop.is_set():
                    err = DeviceError(f"serial link to {self._settings.port!r} lost: {exc}")
                    with contextlib.suppress(RuntimeError):  # the event loop may be gone already
                        loop.call_soon_threadsafe(self._on_reply, err)
                return
            if not chunk:
                continue
            buffer += chunk
            while b"\n" in buffer:
                raw, buffer = buffer.split(b"\n", 1)
                text = raw.rstrip(b"\r").decode("latin-1")
                try:
                    loop.call_soon_threadsafe(self._on_line, text)
                except RuntimeError:  # the event loop closed under us: nobody is listening
                    return

    def _on_line(self, text: str) -> None:
        self.events.data_received.emit(text)
        try:
            reply: vp.Reply | TelerobotError = vp.parse_reply(text)
        except vp.ProtocolError as exc:
            reply = DeviceError(f"{exc} (after {self._last_sent!r})")
        self._on_reply(reply)

    def _on_reply(self, reply: vp.Reply | TelerobotError) -> None:
        self._replies.put_nowait(reply)

    async def _send(self, line: str) -> None:
        if self._serial is None:
            raise DeviceError("serial port is not open")
        self._last_sent = line
        data = line.encode("latin-1") + b"\r"
        try:
            await asyncio.to_thread(self._write, self._serial, data)
        except (serial.SerialException, OSError) as exc:
            raise DeviceError(f"cannot write to {self._settings.port!r}: {exc}") from None

    def _write(self, port: serial.Serial, data: bytes) -> None:
        with self._write_lock:  # a line is never interleaved with another
            port.write(data)

    async def _next_reply(self, timeout: float, waiting_for: str) -> vp.Reply:
        try:
            reply = await asyncio.wait_for(self._replies.get(), timeout)
        except TimeoutError:
            raise DeviceError(
                f"no {waiting_for} from the controller on {self._settings.port!r} within "
                f"{timeout:g} s after {self._last_sent!r}: is it powered on and connected?"
            ) from None
        if isinstance(reply, TelerobotError):
            raise reply
        if isinstance(reply, vp.ControllerError):
            raise DeviceError(f"controller error after {self._last_sent!r}: {reply.reason}")
        return reply

    async def _request(self, line: str, expected: vp.Text | type[vp.Reply]) -> vp.Reply:
        """Send ``line`` and check that the next reply is ``expected`` (a literal
        prompt/banner, or a reply type)."""
        await self._send(line)
        what = repr(expected.text) if isinstance(expected, vp.Text) else expected.__name__
        reply = await self._next_reply(self._settings.reply_timeout, what)
        ok = reply == expected if isinstance(expected, vp.Text) else isinstance(reply, expected)
        if not ok:
            raise DeviceError(f"controller answered {reply} to {line!r}; expected {what}")
        return reply

    # ------------------------------------------------------------ initialisation
    async def _prepare(self) -> None:
        if self._pump is not None:
            self._pump.cancel()
            self._pump = None
        self._reset_abort()
        await self._request("ABORT", vp.Text(vp.PROMPT))
        await self._request(f"EDIT {vp.PROGRAM_NAME}", vp.Text("1."))
        for n, line in enumerate(vp.RESIDENT_PROGRAM, start=2):
            await self._request(line, vp.Text(f"{n}."))
        await self._request("E", vp.Text(vp.PROMPT))
        await self._request(f"EXECUTE {vp.PROGRAM_NAME}", vp.Text(vp.READY_BANNER))
        pos = await self._request("W", vp.Position)
        assert isinstance(pos, vp.Position)
        self._raw = np.radians(pos.joints_deg)
        self._raw_target = None
        self._pump = asyncio.create_task(self._pump_targets(), name="val-serial-pump")

    # ------------------------------------------------------------ motion
    async def _send_target(self, raw_target: FloatArray) -> None:
        if self._pump is None or self._pump.done():
            raise DeviceError("the resident program is not running: initialise the robot")
        self._raw_target = np.asarray(raw_target, dtype=float).copy()
        self._wake.set()

    async def _halt(self) -> None:
        """Drop every target not yet sent and, if an increment is moving, ``ABORT`` it
        at once: the controller brakes the arm to rest at its limit."""
        self._raw_target = None
        async with self._send_lock:  # a line being written is finished first
            if self._on_wire is not None and not self._aborting:
                self._aborting = True
                try:
                    await self._send("ABORT")
                except TelerobotError as exc:
                    self._fail(exc)
        self._wake.set()

    async def _pump_targets(self) -> None:
        try:
            while True:
                await self._wake.wait()
                self._wake.clear()
                while self._raw_target is not None and not self._aborting:
                    if not await self._move_toward_target():
                        break
                    self._report_moved()
                if self._aborting:
                    await self._resume_after_abort()
                self._motion_finished()
        except TelerobotError as exc:
            self._pump = None
            self._fail(exc)

    def _aborted(self, reply: vp.Reply) -> bool:
        """Whether ``reply`` is the monitor's prompt after our ABORT (the arm at rest)."""
        if self._aborting and reply == vp.Text(vp.PROMPT):
            self._abort_prompt = True
        return self._abort_prompt

    async def _move_toward_target(self) -> bool:
        """Send one increment toward the newest target and wait for it to end (or to
        be aborted); False if there was nothing to send."""
        async with self._send_lock:
            # Computed here, under the lock: a stop or a newer target that came while
            # the last line was being written is never overtaken by a stale increment.
            if self._raw_target is None or self._aborting:
                return False
            delta = [round(math.degrees(d), 4) for d in self._raw_target - self._raw]
            if max(abs(d) for d in delta) < _MIN_INCREMENT_DEG:
                return False
            self._seq += 1
            seq = self._seq
            self._on_wire = seq
            await self._send(vp.increment_line(seq, delta))
        try:
            reply = await self._next_reply(self._settings.reply_timeout, f"ACK {seq}")
            if self._aborted(reply):
                return True
            if isinstance(reply, vp.Nak):
                raise DeviceError(f"controller refused increment {seq}: {reply.reason}")
            if not isinstance(reply, vp.Ack) or reply.seq != seq:
                raise DeviceError(
                    f"controller answered {reply} to increment {seq}; expected ACK {seq}"
                )
            done = await self._next_reply(
                reply.duration + self._settings.move_margin, f"DONE {seq}"
            )
            if self._aborted(done):
                return True
            if not isinstance(done, vp.Done) or done.seq != seq:
                raise DeviceError(f"controller answered {done} while increment {seq} was moving")
            self._raw = np.radians(done.joints_deg)
        finally:
            self._on_wire = None
        return True

    async def _resume_after_abort(self) -> None:
        """After ``ABORT``: wait for the prompt (the arm at rest), start ``TRINC``
        again and read where the arm stopped."""
        while not self._abort_prompt:
            reply = await self._next_reply(self._settings.reply_timeout, "'.' after ABORT")
            if isinstance(reply, vp.Done):  # the move ended before ABORT arrived
                self._raw = np.radians(reply.joints_deg)
            self._aborted(reply)
        await self._request(f"EXECUTE {vp.PROGRAM_NAME}", vp.Text(vp.READY_BANNER))
        pos = await self._request("W", vp.Position)
        assert isinstance(pos, vp.Position)
        self._raw = np.radians(pos.joints_deg)
        self._aborting = self._abort_prompt = False
