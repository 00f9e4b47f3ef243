"""Real ``telerobot`` processes for end-to-end tests: ``serving`` is the one way a test
starts a server (harness.servers.serve_for_bench underneath, as the benchmarks do), and
its URL is always ``http://127.0.0.1:PORT/``."""

from __future__ import annotations

import contextlib
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

from harness.servers import serve_for_bench, telerobot_process
from tests.support import TOKEN

BIN = Path(sys.executable).parent / "telerobot"
telerobot = telerobot_process  # any other command: `telerobot("val-emulator", …)`


@contextlib.contextmanager
def serving(
    env: dict[str, str] | None = None,
    *args: str,
    port: int = 0,
    ready: bool = True,
    prefix: tuple[str, ...] = (),
    exe: Path | None = None,
    cwd: Path | None = None,
) -> Iterator[str]:
    """`telerobot serve ARGS` with ``env`` (the operator token is ``TOKEN`` unless
    ``env`` says otherwise), on this HTTP port (0: any) with a throw-away state folder;
    with ``ready`` (the default) once its robot is READY. Yields its base URL. ``exe``:
    another installation's ``telerobot`` (the wheel's), run in ``cwd``."""
    with serve_for_bench(
        *args,
        env={
            "TELEROBOT_OPERATOR_TOKEN": TOKEN,
            "TELEROBOT_SIM_STARTS_AT_HOME": "true",
            # As started (the suite's own processes share the cores; the raised
            # priority is bench.abuse's and tests/test_tuning.py's).
            "TELEROBOT_CPU_PRIORITY": "0",
            **(env or {}),
        },
        prefix=prefix,
        port=port,
        ready=ready,
        exe=exe,
        cwd=cwd,
    ) as (_, base):
        yield base


def free_port() -> int:
    """A TCP port free now, for a server a test stops and starts again on the same port."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port
