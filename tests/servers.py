"""Start ``telerobot`` commands as real processes for end-to-end tests."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

BIN = Path(sys.executable).parent / "telerobot"


@contextmanager
def telerobot(
    *args: str, wait_for: str, timeout: float = 30.0
) -> Iterator[tuple[subprocess.Popen[str], re.Match[str]]]:
    """Run ``telerobot ARGS`` and yield once a line of its output matches ``wait_for``."""
    proc = subprocess.Popen(
        [str(BIN), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.stdout is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    match = None
    try:
        while match is None:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                raise AssertionError(f"telerobot {' '.join(args)} exited:\n{''.join(seen)}")
            seen.append(line)
            match = re.search(wait_for, line)
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"no line matching {wait_for!r} within {timeout} s:\n{''.join(seen)}"
                )
        yield proc, match
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
