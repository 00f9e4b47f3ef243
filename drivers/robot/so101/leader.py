"""``So101Leader``: the SO-101 leader arm (the same six STS3215 servos, their torque
off, moved by the operator's hand), read joint for joint for the joint mirror
(``telerobot master --device so101-leader``).

It shares the follower's Feetech bus (``telerobot.drivers.motors.feetech``) and converts with
its own calibration (``So101Calibration``: a leader is assembled on its own, so its
zeros and directions are its own). Reading never writes a goal: after the handshake
it switches every servo's torque off, so the arm can be moved by hand, and keeps it
off. A servo that stops answering for more than ``MAX_MISSED`` reads in a row is a
``DeviceError`` naming it; the mirror then stops sending and the server's dead-man
stops the follower.
"""

from __future__ import annotations

from pathlib import Path
from typing import Self

import numpy as np
import serial

from telerobot.drivers.base import DeviceError, FloatArray
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.bus import (
    FeetechPort,
    MissCounter,
    identify_servos,
    open_bus,
)
from telerobot.drivers.motors.feetech.protocol import Register
from telerobot.drivers.robot.models import RobotModel
from telerobot.drivers.robot.so101.calibration import So101Calibration
from telerobot.drivers.robot.so101.settings import default_calibration_path

LEADER_CALIBRATION_FILE = "so101-leader-calibration.json"
MAX_MISSED = 3  # reads in a row a servo may miss before the leader is lost
REPLY_TIMEOUT_S = 0.02


def default_leader_calibration() -> Path:
    """Beside the follower's, in the state folder."""
    return default_calibration_path({}).with_name(LEADER_CALIBRATION_FILE)


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
        self._serial, bus = open_bus(self.port_name, self.baudrate, self.reply_timeout)
        self._bus = bus
        try:
            identify_servos(bus, self.calibration, self.port_name)
        except DeviceError as exc:
            self.close()
            raise DeviceError(f"the leader: {exc}") from None
        for i in self.calibration.ids:  # torque off: the operator moves it by hand
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
