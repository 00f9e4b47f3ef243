"""A real Telerobot server for the plugins' tests: `telerobot serve` from the project's own
environment (``TELEROBOT_SERVE``, default ``<repo>/.venv/bin/telerobot``: the server needs
Python 3.11's packages, LeRobot 3.12's; they meet over the network, as they would on two
machines)."""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[3]
TOKEN = "lerobot-plugin-tests-0123456789abcdef"
BIN = Path(sys.executable).parent  # lerobot-record, lerobot-replay
os.environ["HF_HUB_OFFLINE"] = "1"  # LeRobot reads local datasets here: never the Hub


@contextlib.contextmanager
def serving(*args: str, env: dict[str, str] | None = None) -> Iterator[tuple[str, Path]]:
    """`telerobot serve ARGS` on free ports with a throw-away state folder, once its arm
    is READY: its URL and state folder."""
    exe = os.environ.get("TELEROBOT_SERVE", str(REPO / ".venv" / "bin" / "telerobot"))
    with tempfile.TemporaryDirectory() as state:
        proc = subprocess.Popen(
            [
                exe,
                "serve",
                "--http-port",
                "0",
                "--priority-port",
                "0",
                "--viewer-port",
                "0",
                "--state-dir",
                state,
                *args,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={
                **os.environ,
                "PYTHONUNBUFFERED": "1",
                "TELEROBOT_OPERATOR_TOKEN": TOKEN,
                "TELEROBOT_CPU_PRIORITY": "0",
                "TELEROBOT_SIM_STARTS_AT_HOME": "true",
                **(env or {}),
            },
        )
        assert proc.stdout is not None
        seen: list[str] = []
        url = None
        deadline = time.monotonic() + 120
        try:
            while url is None:
                line = proc.stdout.readline()
                if not line and proc.poll() is not None:
                    raise RuntimeError("telerobot serve exited:\n" + "".join(seen))
                seen.append(line)
                found = re.search(r"(http://localhost:\d+/)", line)
                url = found.group(1) if found else None
                if time.monotonic() > deadline:
                    raise RuntimeError("telerobot serve did not start:\n" + "".join(seen))
            threading.Thread(target=lambda: [None for _ in proc.stdout or []], daemon=True).start()
            # (every arm's: a server may drive two)
            while any(a["status"] != "READY" for a in httpx.get(url + "api/v1/robot/arms").json()):
                assert time.monotonic() < deadline, "the arm never became READY"
                time.sleep(0.1)
            yield url, Path(state)
        finally:
            proc.terminate()
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def lerobot_env(url: str, home: Path) -> dict[str, str]:
    """LeRobot's command lines offline, with their caches in ``home``."""
    return {
        **os.environ,
        "TELEROBOT_URL": url,
        "TELEROBOT_OPERATOR_TOKEN": TOKEN,
        "HF_HOME": str(home / "hf"),
        "HF_LEROBOT_HOME": str(home / "lerobot"),
        "HF_HUB_OFFLINE": "1",
    }


def run_lerobot(
    tool: str,
    args: list[str],
    url: str,
    home: Path,
    timeout: float = 300,
    env: dict[str, str] | None = None,
) -> str:
    """A LeRobot command line, headless (its keyboard listener reads no terminal; a
    question it asks on stdin meets its end)."""
    out = subprocess.run(
        [str(BIN / tool), *args],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**lerobot_env(url, home), **(env or {})},
    )
    said = out.stdout + out.stderr
    assert out.returncode == 0, f"{tool} exited with {out.returncode}:\n{said[-6000:]}"
    return said
