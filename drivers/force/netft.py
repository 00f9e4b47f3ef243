"""``NetFtSensor``: an ATI Net F/T (or anything that speaks its RDT protocol over UDP).

A receiving thread asks the sensor to stream, turns counts into newtons and
newton-metres, and hands each record to the shared pipeline (filter, threshold) and
to subscribers. Lost packets are counted from gaps in the RDT sequence; short,
malformed or stale (re-ordered) packets are counted and dropped. When the sensor
falls silent (unplugged, rebooting) the driver says so and keeps asking it to stream,
so it resumes by itself. Timestamps are the receive time on the monotonic clock: the
RDT record carries none.

A sensor that restarted counts its RDT sequence from the start again. A packet far
behind the newest (more than ``REORDER_WINDOW``), or the first one after the driver
had to ask a silent sensor to stream again, is such a restart, not a re-ordered
packet: the driver follows the new sequence at once, counts it (``restarts``) and
says so, rather than dropping as "stale" as many packets as it had received before.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Self

from telerobot.drivers.base import DeviceContext, InvalidCommand
from telerobot.drivers.force import netft_protocol as rdt
from telerobot.drivers.force.netft_settings import NetFtSettings
from telerobot.drivers.force.pipeline import Six
from telerobot.drivers.force.sampled import SampledForceSensor

log = logging.getLogger(__name__)

SEQ_MOD = 1 << 32
# How far behind the newest a packet may be and still be a re-ordered one (dropped as
# stale). UDP on a LAN re-orders a packet by a few places; a sequence that goes back
# further is a sensor that restarted (it counts from the start again).
REORDER_WINDOW = 256


def parse_address(address: str) -> tuple[str, int]:
    host, _, port = address.rpartition(":") if ":" in address else (address, "", "")
    try:
        number = int(port) if port else rdt.RDT_PORT
    except ValueError:
        number = -1
    if not host or not 0 < number < 65536:
        raise InvalidCommand(f"Net F/T address must be HOST or HOST:PORT, got {address!r}")
    return host, number


@dataclass(frozen=True)
class NetFtConfig:
    """What ``NetFtSensor`` reads from the settings: the sensor's address, its
    calibration (from its web page) and the rate it is set to stream at."""

    address: str = f"192.168.1.1:{rdt.RDT_PORT}"
    counts_per_force: float = rdt.COUNTS_PER_FORCE
    counts_per_torque: float = rdt.COUNTS_PER_TORQUE
    rate_hz: float = 1000.0

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        own = NetFtSettings.of(settings)
        return cls(
            address=own.netft_address,
            counts_per_force=own.netft_counts_per_force,
            counts_per_torque=own.netft_counts_per_torque,
            rate_hz=float(settings["force_rate_hz"]),
        )


class NetFtSensor(SampledForceSensor):
    name = "netft"
    thread_name = "netft-receiver"

    def __init__(
        self,
        address: str = f"192.168.1.1:{rdt.RDT_PORT}",
        *,
        counts_per_force: float = rdt.COUNTS_PER_FORCE,
        counts_per_torque: float = rdt.COUNTS_PER_TORQUE,
        rate_hz: float = 1000.0,
        silence_s: float = 0.5,
        time_source: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (counts_per_force > 0 and counts_per_torque > 0):
            raise InvalidCommand("counts per force and per torque must be positive")
        super().__init__(rate_hz)  # the rate the sensor is set to stream at (filter maths)
        self.address = parse_address(address)
        self.counts_per_force = float(counts_per_force)
        self.counts_per_torque = float(counts_per_torque)
        self.silence_s = silence_s
        self._now = time_source
        self._sock: socket.socket | None = None
        self._last_rdt: int | None = None
        self.received = 0
        self.lost = 0  # gaps in the RDT sequence
        self.bad_packets = 0  # wrong size
        self.stale = 0  # older than one already delivered
        self.sensor_status = 0  # the last non-zero status word the sensor reported
        self.silences = 0  # times the sensor fell silent
        self.restarts = 0  # times its sequence started again (a restarted sensor)
        self._asked_again = False  # silent, asked to stream again: a new sequence may come
        self._biased = False  # the sensor was asked to bias itself (a restart forgets it)
        self.error: str | None = None  # what is wrong now (None once data flows again)
        self.last_error: str | None = None

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        config = NetFtConfig.from_settings(settings)
        return cls(
            config.address,
            counts_per_force=config.counts_per_force,
            counts_per_torque=config.counts_per_torque,
            rate_hz=config.rate_hz,
        )

    @property
    def counters(self) -> dict[str, int]:
        return {
            "received": self.received,
            "lost": self.lost,
            "bad_packets": self.bad_packets,
            "stale": self.stale,
            "silences": self.silences,
            "restarts": self.restarts,
        }

    def _send(self, command: int) -> None:
        if self._sock is not None:
            try:
                self._sock.send(rdt.request(command))
            except OSError as exc:  # e.g. no route: the receive loop reports silence
                log.debug("Net F/T request %#x failed: %s", command, exc)

    def tare(self) -> None:
        """The sensor biases itself (RDT command 0x0042); without a link, the pipeline."""
        if self._sock is not None:
            self._send(rdt.CMD_BIAS)
            self._biased = True
        else:
            super().tare()

    def start(self) -> None:
        """Start receiving. Never raises for the network: an unknown host or a missing
        route is reported in ``error`` and retried every second."""
        if self.running:
            return
        self._last_rdt = None
        self._asked_again = False
        super().start()

    def stop(self) -> None:
        self._send(rdt.CMD_STOP)
        super().stop()
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def _where(self) -> str:
        return f"udp://{self.address[0]}:{self.address[1]}"

    def _open(self) -> socket.socket | None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(0.05)
        try:
            sock.connect(self.address)
        except OSError as exc:
            sock.close()
            self._fail(f"cannot reach the Net F/T at {self._where()}: {exc}")
            return None
        return sock

    def _run(self) -> None:
        while self._sock is None and not self._stop.is_set():
            self._sock = self._open()
            if self._sock is None:
                self._stop.wait(1.0)
        if self._sock is not None:
            self._receive(self._sock)

    def _receive(self, sock: socket.socket) -> None:
        self._send(rdt.CMD_STREAM)
        last_rx = asked = self._now()
        while not self._stop.is_set():
            try:
                data = sock.recv(2048)
            except TimeoutError:
                now = self._now()
                if now - last_rx > self.silence_s and now - asked > self.silence_s:
                    new = self.error is None
                    self._fail(
                        f"no data from the Net F/T at {self._where()} for "
                        f"{now - last_rx:.1f} s: is it powered and on the network?"
                    )
                    if new:  # counted once the error says why (a reader sees both)
                        self.silences += 1
                    self._send(rdt.CMD_STREAM)  # it may have rebooted: ask again
                    self._asked_again = True
                    asked = now
                continue
            except OSError as exc:  # ICMP port unreachable and the like
                self._fail(f"Net F/T at {self._where()}: {exc}")
                self._stop.wait(0.05)
                continue
            now = self._now()
            self.on_packet(data, now)
            last_rx = now

    def _fail(self, message: str) -> None:
        if message != self.error:
            log.warning("%s", message)
        self.error = self.last_error = message

    def _restarted(self, last: int, seq: int) -> None:
        self.restarts += 1
        log.warning(
            "the Net F/T at %s restarted (its RDT sequence went back from %d to %d): "
            "following its new sequence%s",
            self._where(),
            last,
            seq,
            ": its bias was reset, tare it again" if self._biased else "",
        )
        self._biased = False

    def on_packet(self, data: bytes, now: float) -> None:
        """One datagram from the sensor (the receiving thread calls this)."""
        record = rdt.parse_record(data)
        if record is None:
            self.bad_packets += 1
            return
        last = self._last_rdt
        if last is not None:
            gap = (record.rdt_seq - last) % SEQ_MOD
            if gap == 0 or gap >= SEQ_MOD // 2:  # a repeat or an older packet
                behind = (last - record.rdt_seq) % SEQ_MOD
                if not self._asked_again and behind <= REORDER_WINDOW:
                    self.stale += 1  # re-ordered (or repeated) on the way
                    return
                self._restarted(last, record.rdt_seq)
            else:
                self.lost += gap - 1
        self._asked_again = False
        self._last_rdt = record.rdt_seq
        self.received += 1
        self.error = None
        if record.status:
            self.sensor_status = record.status
        f, t = self.counts_per_force, self.counts_per_torque
        c = record.counts
        raw: Six = (c[0] / f, c[1] / f, c[2] / f, c[3] / t, c[4] / t, c[5] / t)
        self._deliver(record.rdt_seq, now, raw)
