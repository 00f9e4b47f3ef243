"""A ``telerobot`` command run as the user runs it, its every output line kept: for the
tests that read what a command says (``servers.telerobot`` waits for one line and then
drains the rest unread)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
from collections.abc import Iterator
from contextlib import contextmanager

from tests.support.servers import BIN
from tests.support.waiting import until


class Running:
    """``telerobot ARGS`` in its own process, stdout and stderr as one stream of lines."""

    def __init__(self, *args: str, env: dict[str, str] | None = None) -> None:
        self.proc = subprocess.Popen(
            [str(BIN), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
        )
        self.lines: list[str] = []
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._lock:
                self.lines.append(line.rstrip("\n"))

    @property
    def output(self) -> str:
        with self._lock:
            return "\n".join(self.lines)

    def said(self, pattern: str) -> list[str]:
        """The lines so far that match ``pattern`` (a regular expression)."""
        with self._lock:
            return [line for line in self.lines if re.search(pattern, line)]

    def wait_for(self, pattern: str, timeout: float = 30.0) -> str:
        """The first line matching ``pattern``, once said (fails after ``timeout``, showing
        the output so far)."""
        until(
            lambda: self.said(pattern) or self.proc.poll() is not None,
            timeout=timeout,
            what=lambda: f"no line matching {pattern!r} in:\n{self.output}",
            poll=0.05,
        )
        found = self.said(pattern)
        assert found, f"exited ({self.proc.returncode}) before {pattern!r}:\n{self.output}"
        return found[0]

    def interrupt(self, timeout: float = 30.0) -> int:
        """Ctrl+C, then its exit code once it has ended and its output is all read."""
        self.proc.send_signal(signal.SIGINT)
        return self.wait(timeout)

    def wait(self, timeout: float = 60.0) -> int:
        code = self.proc.wait(timeout=timeout)
        self._reader.join(timeout=10)
        return code

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._reader.join(timeout=10)


@contextmanager
def running(*args: str, env: dict[str, str] | None = None) -> Iterator[Running]:
    """``Running`` for the block's length; killed at its end if still running."""
    command = Running(*args, env=env)
    try:
        yield command
    finally:
        command.kill()
