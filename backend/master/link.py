"""A client of the priority channel (``backend.realtime.priority``): one TCP socket,
length-prefixed messages, a reader thread that hands every force sample over the
moment it arrives. Thread-safe sends; used by the master-arm bridge and the
force-under-video benchmark."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from backend.netprio import mark_high_priority
from backend.realtime import messages as m
from drivers.base import DeviceError, ForceSample

ForceCallback = Callable[[ForceSample, float], None]  # sample, receive time (monotonic)


@dataclass
class Reply:
    name: str
    fields: dict[str, Any]
    text: str


class PriorityLink:
    def __init__(
        self,
        host: str,
        port: int,
        token: str = "",
        *,
        on_force: ForceCallback | None = None,
        on_state: Callable[[dict[str, Any]], None] | None = None,
        on_reply: Callable[[Reply], None] | None = None,
        timeout_s: float = 5.0,
    ) -> None:
        self.on_force = on_force
        self.on_state = on_state
        self.on_reply = on_reply
        self._send_lock = threading.Lock()
        self._seq = 0
        self.operator = False
        self.client_id = ""
        self.offset = 0.0  # server clock − this machine's monotonic clock (s), from PING
        self.best_rtt = float("inf")
        self.closed_reason: str | None = None
        self.received = 0
        try:
            self.sock = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise DeviceError(
                f"cannot reach the priority channel at tcp://{host}:{port}: {exc}"
            ) from None
        mark_high_priority(self.sock)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._welcome = threading.Event()
        self._pings: dict[int, float] = {}
        self._send(m.encode(m.HELLO, m.PROTOCOL_VERSION, 0, token.encode("ascii")))
        self._reader = threading.Thread(target=self._read, name="priority-link", daemon=True)
        self._reader.start()
        if not self._welcome.wait(timeout_s):
            self.close()
            raise DeviceError(
                f"no WELCOME from tcp://{host}:{port} within {timeout_s:g} s"
                + (f": {self.closed_reason}" if self.closed_reason else "")
            )
        self.sock.settimeout(None)

    # ------------------------------------------------------------ sending
    def _next(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        return self._seq

    def _send(self, message: bytes) -> None:
        with self._send_lock:
            self.sock.sendall(m.LENGTH.pack(len(message)) + message)

    def lease(self, action: m.LeaseAction) -> int:
        seq = self._next()
        self._send(m.encode(m.LEASE, seq, int(action)))
        return seq

    def cartesian(self, dX: tuple[float, float, float], rotvec: tuple[float, float, float],
                  frame: m.Frame = m.Frame.BASE) -> int:  # fmt: skip
        seq = self._next()
        self._send(m.encode(m.CART_INC, seq, time.monotonic(), int(frame), *dX, *rotvec))
        return seq

    def heartbeat(self) -> None:
        self._send(m.encode(m.HEARTBEAT, self._next(), time.monotonic()))

    def estop(self) -> None:
        self._send(m.encode(m.ESTOP, self._next(), time.monotonic()))

    def ping(self) -> None:
        seq = self._next()
        t0 = time.monotonic()
        self._pings[seq] = t0
        self._send(m.encode(m.PING, seq, t0))

    def send_raw(self, message: bytes) -> None:
        """One framed message as it is (for tests of the server's checks)."""
        self._send(message)

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        if self._reader.is_alive() and self._reader is not threading.current_thread():
            self._reader.join(timeout=2)

    # ------------------------------------------------------------ receiving
    def _read(self) -> None:
        buf = bytearray()
        try:
            while True:
                data = self.sock.recv(65536)
                if not data:
                    self.closed_reason = self.closed_reason or "the server closed the channel"
                    return
                now = time.monotonic()
                buf += data
                while len(buf) >= m.LENGTH.size:
                    (size,) = m.LENGTH.unpack_from(buf)
                    if len(buf) < m.LENGTH.size + size:
                        break
                    message = bytes(buf[m.LENGTH.size : m.LENGTH.size + size])
                    del buf[: m.LENGTH.size + size]
                    self._dispatch(message, now)
        except OSError as exc:
            self.closed_reason = self.closed_reason or str(exc)

    def _dispatch(self, message: bytes, now: float) -> None:
        if message[0] == m.FORCE.type_id:
            for seq, t, values in m.decode_force(message):
                self.received += 1
                if self.on_force is not None:
                    self.on_force(ForceSample(seq, t, values), now)  # type: ignore[arg-type]
            return
        msg, fields, text = m.decode(message)
        if msg is m.WELCOME:
            self.operator = int(fields["role"]) == 1
            self.client_id = text
            self._welcome.set()
        elif msg is m.STATE:
            if self.on_state is not None:
                self.on_state(fields)
            return
        elif msg is m.PONG:
            t0 = self._pings.pop(int(fields["seq"]), None)
            if t0 is not None:
                rtt = now - t0 - (float(fields["t2"]) - float(fields["t1"]))
                if rtt < self.best_rtt:
                    self.best_rtt = rtt
                    self.offset = (float(fields["t1"]) - t0 + float(fields["t2"]) - now) / 2
        elif msg is m.ERROR and not self._welcome.is_set():
            self.closed_reason = text
        if self.on_reply is not None:
            self.on_reply(Reply(msg.name, fields, text))
