"""One Feetech servo bus (``protocol``'s packets over a serial port, a pty or
``socket://host:port``), shared by every arm built of these servos: the SO-101
follower (``telerobot.drivers.robot.so101.arm``) and its leader (``.leader``).

``FeetechPort`` sends a packet and collects the replies of the servos it asked, under
one lock (a command and a read never interleave on the wire); ``open_bus`` opens a
port; ``identify_servos`` names a servo that is silent or of another model;
``MissCounter`` counts the reads each servo missed in a row.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Sequence
from typing import Protocol

import serial

from telerobot.drivers.base import DeviceError
from telerobot.drivers.motors.feetech import protocol as ft
from telerobot.drivers.motors.feetech.protocol import Register

log = logging.getLogger(__name__)

# Bytes past what a reply should hold that a transaction still reads (skipped
# garbage, stray packets); past it, the read ends and the servos not heard count a miss.
MAX_REPLY_JUNK = 512


class ServoNames(Protocol):
    """The servos on a bus and what to call each (an arm's calibration)."""

    @property
    def ids(self) -> Sequence[int]: ...

    def label(self, servo_id: int) -> str: ...


class NoAnswer(DeviceError):
    """The bus, or servos on it, did not answer (rather than answering wrong): worth
    trying again at start-up."""


class MissCounter:
    """Consecutive reads each servo did not answer; a servo past ``limit`` is lost."""

    def __init__(self, ids: Sequence[int], limit: int) -> None:
        if limit < 1:
            raise ValueError("the missed-read limit is at least 1")
        self.limit = limit
        self.missed = dict.fromkeys(ids, 0)

    def update(self, answered: Sequence[int]) -> list[int]:
        """Count a read; the servos that have now missed more than ``limit`` in a row."""
        for i in self.missed:
            self.missed[i] = 0 if i in answered else self.missed[i] + 1
        return [i for i, n in self.missed.items() if n > self.limit]


class FeetechPort:
    """One bus: a packet out, the replies of the servos it asked, under one lock."""

    def __init__(self, port: serial.Serial, name: str, reply_timeout: float) -> None:
        self.port = port
        self.name = name
        self.reply_timeout = reply_timeout
        self.lock = threading.Lock()
        self._reader = ft.PacketReader()
        self.counters = {"transactions": 0, "corrupt": 0, "stray": 0, "flooded": 0}

    def transact(self, packet: bytes, ids: Sequence[int]) -> dict[int, ft.Packet]:
        """Send ``packet``; the status packets of ``ids`` that came within the reply
        timeout (a servo missing from the result did not answer)."""
        with self.lock:
            self.counters["transactions"] += 1
            try:
                self.port.reset_input_buffer()  # late replies to an earlier request
                self._reader.clear()
                self.port.write(packet)
                if not ids:
                    return {}
                return self._collect(ids)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                raise NoAnswer(f"the servo bus on {self.name!r} failed: {exc}") from None

    def _collect(self, ids: Sequence[int]) -> dict[int, ft.Packet]:
        wanted = set(ids)
        got: dict[int, ft.Packet] = {}
        budget = len(ids) * (ft.MIN_PACKET + ft.MAX_LENGTH) + MAX_REPLY_JUNK
        deadline = time.monotonic() + self.reply_timeout
        received = 0
        while len(got) < len(wanted) and time.monotonic() < deadline:
            if received > budget:
                self.counters["flooded"] += 1
                break
            chunk = self.port.read(max(1, min(self.port.in_waiting, budget)))
            received += len(chunk)
            self._reader.feed(chunk)
            while True:
                try:
                    p = self._reader.next()
                except ft.ProtocolError as exc:
                    self.counters["corrupt"] += 1
                    log.debug("%s: %s", self.name, exc)
                    continue
                if p is None:
                    break
                if p.id in wanted and p.id not in got:
                    got[p.id] = p
                else:
                    self.counters["stray"] += 1
        return got


def open_bus(port: str, baudrate: int, reply_timeout: float) -> tuple[serial.Serial, FeetechPort]:
    """The servo bus on ``port`` (a device, a pty, socket://host:port); blocking."""
    try:
        link = serial.serial_for_url(
            port, baudrate=baudrate, timeout=min(0.005, reply_timeout), write_timeout=1.0
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise NoAnswer(f"cannot open the servo bus {port!r}: {exc}") from None
    # socket://: pyserial leaves Nagle on, and a goal written just before a read
    # would then wait for the peer's delayed ACK (40 ms), past the reply timeout.
    sock = getattr(link, "_socket", None)
    if isinstance(sock, socket.socket):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return link, FeetechPort(link, port, reply_timeout)


def identify_servos(bus: FeetechPort, cal: ServoNames, port: str) -> None:
    """PING each servo and read its model number: a silent one, or one that is not an
    STS3215, is named (``DeviceError``); blocking."""
    silent = [i for i in cal.ids if i not in bus.transact(ft.ping(i), [i])]
    if len(silent) == len(cal.ids) > 1:  # the bus, not a servo: said once
        raise NoAnswer(
            f"none of the {len(silent)} servos answers on {port!r}: check the servos' "
            "power and the bus's adapter and cable"
        )
    if silent:
        names = ", ".join(cal.label(i) for i in silent)
        verb = "does" if len(silent) == 1 else "do"
        raise NoAnswer(
            f"{names} {verb} not answer on {port!r}: check its power and "
            "cable, and that its id is set"
        )
    for i in cal.ids:
        reply = bus.transact(ft.read(i, Register.MODEL_NUMBER, 2), [i])
        if i not in reply or len(reply[i].params) != 2:
            raise NoAnswer(f"{cal.label(i)} did not send its model number")
        model = ft.u16(reply[i].params)
        if model != ft.STS3215_MODEL:
            raise DeviceError(
                f"{cal.label(i)} is a servo of model {model}, not an STS3215 ({ft.STS3215_MODEL})"
            )
