"""A Net F/T that answers RDT requests over UDP, for tests and demos
(``telerobot netft-emulator``). It streams a scripted signal at the configured rate
to whoever asked, biases on request, and can drop packets or send garbage on demand
so the driver's loss and error counting can be exercised."""

from __future__ import annotations

import math
import socket
import threading
import time
from collections.abc import Callable

from telerobot.drivers.force import netft_protocol as rdt
from telerobot.drivers.force.pipeline import Six


def default_signal(t: float) -> Six:
    """A light, slowly varying push along z, with an offset for the bias to remove."""
    return (0.5, -0.25, 2.0 + 1.5 * math.sin(2 * math.pi * 0.5 * t), 0.01, 0.02, 0.0)


class NetFtEmulator:
    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 0,
        *,
        rate_hz: float = 1000.0,
        signal: Callable[[float], Six] = default_signal,
        counts_per_force: float = rdt.COUNTS_PER_FORCE,
        counts_per_torque: float = rdt.COUNTS_PER_TORQUE,
    ) -> None:
        self.rate_hz = rate_hz
        self.signal = signal
        self.counts_per_force = counts_per_force
        self.counts_per_torque = counts_per_torque
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind((host, port))
        self._sock.settimeout(0.001)
        self.address = self._sock.getsockname()
        self._target: tuple[str, int] | None = None
        self._remaining = 0  # 0: until told to stop
        self._bias: Six = (0.0,) * 6
        self._rdt_seq = 0
        self._ft_seq = 0
        self._drop = 0
        self.sent = 0
        self.requests: list[int] = []  # commands received, in order
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="netft-emulator", daemon=True)

    @property
    def url(self) -> str:
        return f"{self.address[0]}:{self.address[1]}"

    def start(self) -> NetFtEmulator:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2)
        self._sock.close()

    def __enter__(self) -> NetFtEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def streaming(self) -> bool:
        return self._target is not None

    def reboot(self) -> None:
        """Forget the client and the bias and count the RDT sequence from the start
        again, as a power cycle would."""
        self._target = None
        self.restart_sequence()

    def restart_sequence(self) -> None:
        """Forget the bias and count the RDT sequence from the start again while
        streaming on: a sensor back from a power dip before its client noticed."""
        with self._lock:
            self._rdt_seq = self._ft_seq = 0
            self._bias = (0.0,) * 6

    def drop(self, packets: int) -> None:
        """Skip sending the next ``packets`` records (their sequence numbers are used)."""
        with self._lock:
            self._drop += packets

    def send_raw(self, data: bytes) -> None:
        """Send ``data`` to the streaming client as it is (malformed packets, for tests)."""
        if self._target is not None:
            self._sock.sendto(data, self._target)

    def _counts(self, values: Six) -> tuple[int, int, int, int, int, int]:
        f, t = self.counts_per_force, self.counts_per_torque
        v = [x - b for x, b in zip(values, self._bias, strict=True)]
        return (
            round(v[0] * f),
            round(v[1] * f),
            round(v[2] * f),
            round(v[3] * t),
            round(v[4] * t),
            round(v[5] * t),
        )

    def _handle(self, data: bytes, sender: tuple[str, int]) -> None:
        parsed = rdt.parse_request(data)
        if parsed is None:
            return  # a real sensor ignores what it does not understand
        command, count = parsed
        self.requests.append(command)
        if command == rdt.CMD_STREAM:
            self._target, self._remaining = sender, count
        elif command == rdt.CMD_STOP:
            self._target = None
        elif command == rdt.CMD_BIAS:
            self._bias = self.signal(time.monotonic())

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                data, sender = self._sock.recvfrom(64)
                self._handle(data, sender)
            except (TimeoutError, BlockingIOError):
                pass
            except OSError:
                if self._stop.is_set():
                    return
            now = time.monotonic()
            if self._target is None:
                next_t = now
                continue
            if now < next_t:
                time.sleep(min(next_t - now, 0.001))
                continue
            next_t = max(next_t + 1.0 / self.rate_hz, now - 0.1)  # no burst after a stall
            with self._lock:  # one step with a restart of the sequence, never half of it
                self._rdt_seq = rdt_seq = (self._rdt_seq + 1) % (1 << 32)
                self._ft_seq = ft_seq = (self._ft_seq + 1) % (1 << 32)
                dropping = self._drop > 0
                self._drop -= dropping
            if not dropping:
                record = rdt.Record(rdt_seq, ft_seq, 0, self._counts(self.signal(now)))
                try:
                    self._sock.sendto(record.pack(), self._target)
                    self.sent += 1
                except OSError:
                    pass
            if self._remaining:
                self._remaining -= 1
                if self._remaining == 0:
                    self._target = None
