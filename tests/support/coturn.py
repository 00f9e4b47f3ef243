"""A real TURN server for tests: Debian's coturn (`make turn-deps` installs it), started
with the TURN REST API's shared secret on free ports of one address, and stopped."""

from __future__ import annotations

import contextlib
import os
import random
import re
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

TURNSERVER = "turnserver"
RELAY_PORTS = 200  # relay addresses one server may hand out (two per viewer here)


@dataclass
class Coturn:
    host: str
    port: int
    secret: str
    log_path: Path
    process: subprocess.Popen[bytes]

    @property
    def url(self) -> str:
        """Its TURN URL over UDP (credentials minted from ``secret``)."""
        return f"turn:{self.host}:{self.port}?transport=udp"

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    def usage(self) -> list[dict[str, str | int]]:
        """What each closed allocation carried, from the log: ``side`` "client" (between
        the TURN client and coturn) or "peer" (between its relay address and its peers:
        what was relayed), ``username``, packets and bytes received (rp, rb) and sent
        (sp, sb) on that side."""
        return [
            {
                "side": "peer" if m["peer"] else "client",
                "username": m["user"],
                **{k: int(m[k]) for k in ("rp", "rb", "sp", "sb")},
            }
            for m in USAGE.finditer(self.log())
        ]


# coturn 4.6 at the end of an allocation: "session 0…1: usage: realm=<r>, username=<u>,
# rp=…, rb=…, sp=…, sb=…" and the same for its peers ("session 0…1: peer usage: …").
USAGE = re.compile(
    r"(?P<peer>peer )?usage: realm=<[^>]*>, username=<(?P<user>[^>]*)>, rp=(?P<rp>\d+),"
    r" rb=(?P<rb>\d+), sp=(?P<sp>\d+), sb=(?P<sb>\d+)"
)


def _free_udp_and_tcp_port(host: str) -> int:
    """A port free for both UDP and TCP on ``host`` (TURN listens on both)."""
    for _ in range(50):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
            udp.bind((host, 0))
            port: int = udp.getsockname()[1]
            with socket.socket() as tcp:
                try:
                    tcp.bind((host, port))
                except OSError:
                    continue
                return port
    raise RuntimeError(f"no port free for both UDP and TCP on {host}")


def _stun_binding(host: str, port: int, timeout: float) -> bool:
    """Does a STUN server answer a Binding request there (RFC 5389, no attributes)?"""
    txid = os.urandom(12)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.settimeout(timeout)
        s.sendto(struct.pack("!HHI", 0x0001, 0, 0x2112A442) + txid, (host, port))
        try:
            data = s.recv(2048)
        except OSError:
            return False
    return len(data) >= 20 and data[:2] == b"\x01\x01" and data[8:20] == txid


@contextlib.contextmanager
def coturn(secret: str, host: str = "127.0.0.1") -> Iterator[Coturn]:
    """`turnserver` with ``use-auth-secret`` + ``static-auth-secret=secret``, listening
    and relaying on ``host`` (loopback peers allowed, so two relays here can reach each
    other), no TLS, no CLI, a log in a temporary folder; stopped on leaving."""
    if shutil.which(TURNSERVER) is None:
        pytest.fail("Debian's coturn (turnserver) is missing: `make test` installs it")
    port = _free_udp_and_tcp_port(host)
    low = random.randrange(20_000, 30_000 - RELAY_PORTS)  # below Linux's ephemeral ports
    with tempfile.TemporaryDirectory(prefix="coturn-") as tmp:
        folder = Path(tmp)
        log_path = folder / "turn.log"
        config = folder / "turnserver.conf"
        config.write_text(
            "\n".join(
                [
                    f"listening-ip={host}",
                    f"listening-port={port}",
                    f"relay-ip={host}",
                    f"min-port={low}",
                    f"max-port={low + RELAY_PORTS - 1}",
                    "use-auth-secret",
                    f"static-auth-secret={secret}",
                    "realm=telerobot.test",
                    "fingerprint",
                    "no-tls",
                    "no-dtls",
                    "no-cli",
                    "no-rfc5780",
                    "allow-loopback-peers",
                    f"userdb={folder / 'turndb'}",
                    f"pidfile={folder / 'turnserver.pid'}",
                    f"log-file={log_path}",
                    "simple-log",
                    "no-stdout-log",
                    "verbose",
                ]
            )
            + "\n"
        )
        process = subprocess.Popen(
            [TURNSERVER, "-c", str(config)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,  # a Ctrl-C of the tests is not its to see
        )
        server = Coturn(host, port, secret, log_path, process)
        try:
            deadline = time.monotonic() + 10
            while not _stun_binding(host, port, 0.2):
                if process.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"turnserver did not start (exit {process.poll()}):\n{server.log()[-2000:]}"
                    )
            yield server
        finally:
            process.send_signal(signal.SIGTERM)
            try:
                process.wait(5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)
