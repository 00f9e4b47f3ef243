"""Start ``telerobot`` commands as real processes for end-to-end tests."""

from __future__ import annotations

import contextlib
import socket
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

from bench.common import telerobot_process

BIN = Path(sys.executable).parent / "telerobot"
telerobot = telerobot_process


@contextlib.contextmanager
def served(token: str, **env: str) -> Iterator[str]:
    """`telerobot serve` with this operator token, a throw-away state folder and any
    port; yields its base URL (http://127.0.0.1:PORT, no trailing slash)."""
    with (
        tempfile.TemporaryDirectory() as state,
        telerobot_process(
            "serve", "--http-port", "0", "--state-dir", state,
            wait_for=r"(http://localhost:\d+/)",
            env={"TELEROBOT_OPERATOR_TOKEN": token, **env},
        ) as (_, match),
    ):  # fmt: skip
        yield match.group(1).replace("localhost", "127.0.0.1").rstrip("/")


def free_port() -> int:
    """A TCP port free now, for a server a test stops and starts again on the same port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


@contextlib.contextmanager
def serving(env: dict[str, str], port: int = 0) -> Iterator[str]:
    """`telerobot serve` with ``env`` on this HTTP port (0: any) and a throw-away state
    folder, once its robot is READY; yields its base URL (http://localhost:PORT/)."""
    with (
        tempfile.TemporaryDirectory() as state,
        telerobot_process(
            "serve", "--http-port", str(port), "--state-dir", state,
            wait_for=r"(http://localhost:\d+/)", env=env,
        ) as (_, match),
    ):  # fmt: skip
        base = match.group(1)
        deadline = time.monotonic() + 30
        while httpx.get(base + "api/v1/robot/state").json()["status"] != "READY":
            assert time.monotonic() < deadline, "the robot never became READY"
            time.sleep(0.2)
        yield base
