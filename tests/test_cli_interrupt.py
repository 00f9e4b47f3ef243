"""Ctrl+C on ``telerobot serve`` as at a terminal: SIGINT to the whole process group
(the server, its media worker), which ends with status 0, says it stopped, and prints
no traceback (it printed two ``KeyboardInterrupt`` tracebacks and exited with −2)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tests.support import TOKEN

BIN = Path(sys.executable).parent / "telerobot"


def test_ctrl_c_stops_the_server_with_status_0_and_no_traceback() -> None:
    with tempfile.TemporaryDirectory() as state:
        proc = subprocess.Popen(
            [
                str(BIN),
                "serve",
                "--http-port",
                "0",
                "--priority-port",
                "0",
                "--viewer-port",
                "0",
                "--state-dir",
                state,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={
                **os.environ,
                "PYTHONUNBUFFERED": "1",
                "TELEROBOT_OPERATOR_TOKEN": TOKEN,
                "TELEROBOT_CPU_PRIORITY": "0",
            },
            start_new_session=True,  # its own process group, as a terminal's job
        )
        assert proc.stdout is not None
        seen: list[str] = []
        deadline = time.monotonic() + 90
        try:
            while not any(re.search(r"Telerobot is running on", line) for line in seen):
                line = proc.stdout.readline()
                assert line or proc.poll() is None, "".join(seen)
                seen.append(line)
                assert time.monotonic() < deadline, "".join(seen)
            os.killpg(proc.pid, signal.SIGINT)  # what the terminal does on Ctrl+C
            rest, _ = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    out = "".join(seen) + rest
    assert proc.returncode == 0, out[-3000:]
    assert "Traceback" not in out and "KeyboardInterrupt" not in out, out[-3000:]
    assert "Telerobot stopped." in out
