"""``So101Leader``: the SO-101 leader arm (the same six STS3215 servos, their torque
off, moved by the operator's hand), read joint for joint for the joint mirror
(``telerobot master --device so101-leader``).

It speaks the follower's bus protocol (``feetech``, ``FeetechPort``) and converts with
its own calibration (``So101Calibration``: a leader is assembled on its own, so its
zeros and directions are its own). Reading never writes a goal: after the handshake
it switches every servo's torque off, so the arm can be moved by hand, and keeps it
off. A servo that stops answering for more than ``MAX_MISSED`` reads in a row is a
``DeviceError`` naming it; the mirror then stops sending and the server's dead-man
stops the follower.
"""

from __future__ import annotations

import os
import socket
from pathlib import Path
from typing import Self

import numpy as np
import serial

from drivers.base import DeviceError, FloatArray
from drivers.robot.models import RobotModel
from drivers.robot.so101 import feetech as ft
from drivers.robot.so101.arm import FeetechPort, MissCounter
from drivers.robot.so101.calibration import So101Calibration
from drivers.robot.so101.feetech import Register

LEADER_CALIBRATION_FILE = "so101-leader-calibration.json"
MAX_MISSED = 3  # reads in a row a servo may miss before the leader is lost
REPLY_TIMEOUT_S = 0.02


def default_leader_calibration() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "telerobot" / LEADER_CALIBRATION_FILE


class So101Leader:
    name = "so101-leader"

    def __init__(
        self,
        port: str,
        calibration: So101Calibration,
        *,
        baudrate: int = ft.DEFAULT_BAUDRATE,
        reply_timeout: float = REPLY_TIMEOUT_S,
    ) -> None:
        self.port_name = port
        self.calibration = calibration
        self.joint_names = calibration.joint_names
        self.baudrate = baudrate
        self.reply_timeout = reply_timeout
        self._serial: serial.Serial | None = None
        self._bus: FeetechPort | None = None
        self._misses = MissCounter(calibration.ids, MAX_MISSED)
        self._last: list[float] | None = None
        self.reads = 0

    @classmethod
    def from_options(
        cls, model: RobotModel, *, port: str, baudrate: int, calibration: str | None
    ) -> Self:
        if model.name != "so101":
            raise DeviceError(f"an SO-101 leader mirrors an SO-101, not the {model.title}")
        path = default_leader_calibration() if calibration is None else Path(calibration)
        cal = So101Calibration.load(path, model.joint_names)
        if cal is None:
            raise DeviceError(
                f"the SO-101 leader has no calibration at {path}: record one for it "
                "(its zeros are its own), or give its file with --leader-calibration"
            )
        return cls(port, cal, baudrate=baudrate)

    def open(self) -> None:
        try:
            self._serial = serial.serial_for_url(
                self.port_name, baudrate=self.baudrate, timeout=0.005, write_timeout=1.0
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DeviceError(f"cannot open the leader's bus {self.port_name!r}: {exc}") from None
        sock = getattr(self._serial, "_socket", None)  # socket://: no Nagle delay
        if isinstance(sock, socket.socket):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        bus = self._bus = FeetechPort(self._serial, self.port_name, self.reply_timeout)
        cal = self.calibration
        for i in cal.ids:
            reply = bus.transact(ft.read(i, Register.MODEL_NUMBER, 2), [i])
            if i not in reply or len(reply[i].params) != 2:
                self.close()
                raise DeviceError(
                    f"the leader's {cal.label(i)} does not answer on {self.port_name!r}: "
                    "check its power and cable"
                )
            if ft.u16(reply[i].params) != ft.STS3215_MODEL:
                self.close()
                raise DeviceError(f"the leader's {cal.label(i)} is not an STS3215")
            # Torque off: the operator moves the leader by hand.
            bus.transact(ft.write(i, Register.TORQUE_ENABLE, b"\x00"), [i])

    def close(self) -> None:
        if self._serial is not None:
            self._serial.close()
        self._serial = None
        self._bus = None

    def read(self) -> FloatArray:
        """The leader's joints (model radians): one sync read of every servo."""
        if self._bus is None:
            raise DeviceError("the leader is not open")
        cal = self.calibration
        ids = list(cal.ids)
        replies = self._bus.transact(ft.sync_read(Register.PRESENT_POSITION, 2, ids), ids)
        answered = [i for i, p in replies.items() if len(p.params) == 2]
        lost = self._misses.update(answered)
        if lost:
            names = ", ".join(cal.label(i) for i in lost)
            raise DeviceError(f"the leader's {names} stopped answering")
        previous = self._last or [0.0] * len(ids)
        steps = [
            float(ft.decode_signed(ft.u16(replies[i].params), 15))  # as the follower reads it
            if i in answered
            else previous[k]
            for k, i in enumerate(ids)
        ]
        if self._last is None and len(answered) < len(ids):
            raise DeviceError("the leader's first read was not answered by every servo")
        self._last = steps
        self.reads += 1
        return np.asarray(cal.to_radians(steps), dtype=float)
