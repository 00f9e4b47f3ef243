"""How a device emulator is reached, as the real device would be: on a pseudo-
terminal (``url`` is its device path, for a serial driver) or a TCP port (``url`` is
``socket://host:port``, pyserial's URL), served by a thread of its own (docs/architecture.md,
rule 4). An emulator's link says only what it does with the bytes that come
(``_received``, returning its reply) and, if it acts on its own, what it says when
(``_wait_s``, ``_tick``), and its ``on_pty``/``on_tcp`` constructors (which call
``_open_pty``/``_open_tcp``); one TCP client at a time, as one cable."""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import threading
import time
import tty
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Self

log = logging.getLogger(__name__)


class EmulatorLink(ABC):
    thread_name = "emulator"

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self.url = ""
        self._master: int | None = None
        self._slave: int | None = None
        self._listener: socket.socket | None = None
        self._client: socket.socket | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---------------------------------------------------------- what an emulator says
    @abstractmethod
    def _received(self, data: bytes) -> bytes:
        """Bytes from the driver; the emulator's reply (b"": none)."""

    def _connected(self) -> None:
        """A new TCP client: a fresh cable (e.g. forget a half-received line)."""
        return None  # nothing to forget by default

    def _wait_s(self) -> float:
        """How long the link may wait for bytes before ``_tick`` (an emulator that
        acts on its own, e.g. ends a move, says when)."""
        return 0.05

    def _tick(self) -> bytes:
        """What the emulator says on its own after each wait (b"": nothing)."""
        return b""

    # ---------------------------------------------------------- making one
    def _open_pty(self) -> Self:
        self._master, self._slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(self._slave)  # no echo, no line discipline: bytes pass as sent
        self.url = os.ttyname(self._slave)
        return self

    def _open_tcp(self, host: str = "127.0.0.1", port: int = 0) -> Self:
        self._listener = socket.create_server((host, port))
        h, p = self._listener.getsockname()[:2]
        self.url = f"socket://{h}:{p}"
        return self

    def start(self) -> Self:
        self._thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        for s in (self._client, self._listener):
            if s is not None:
                s.close()

    def drop_client(self) -> None:
        """Close the TCP connection, as a cable pulled out would."""
        if self._client is not None:
            with contextlib.suppress(OSError):
                self._client.shutdown(socket.SHUT_RDWR)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---------------------------------------------------------- thread
    def _send(self, data: bytes) -> None:
        if not data:
            return
        try:
            if self._master is not None:
                os.write(self._master, data)
            elif self._client is not None:
                self._client.sendall(data)
        except OSError as exc:
            log.info("emulator could not write: %s", exc)

    def _run(self) -> None:
        while not self._stop.is_set():
            fds: list[int | socket.socket] = []
            for fd in (self._master, self._listener, self._client):
                if fd is not None:
                    fds.append(fd)
            readable, _, _ = select.select(fds, [], [], self._wait_s())
            for r in readable:
                if r is self._listener:
                    self._accept()
                else:
                    self._read(r)
            self._send(self._tick())

    def _accept(self) -> None:
        assert self._listener is not None
        conn, _ = self._listener.accept()
        if self._client is not None:
            self._client.close()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._client = conn
        self._connected()

    def _read(self, r: int | socket.socket) -> None:
        try:
            data = os.read(r, 4096) if isinstance(r, int) else r.recv(4096)
        except OSError:
            data = b""
        if not data:
            if isinstance(r, socket.socket):
                r.close()
                self._client = None
            else:
                time.sleep(0.01)  # pty with no reader on the slave side yet
            return
        self._send(self._received(data))
