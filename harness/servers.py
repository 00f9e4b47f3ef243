"""Starting ``telerobot`` as its own process: ``serve_for_bench``, the one way the
benchmarks and the end-to-end tests start a server (tests/support/servers.py wraps it),
and ``telerobot_process`` for the other commands."""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

# What the newest server started here said of its 1 kHz threads (GET /api/v1/health).
SERVER_SCHEDULING: dict[str, str] = {}
UNPRIVILEGED_UID = 65534  # nobody: no rights, no RLIMIT_RTPRIO


def as_user(uid: int | None) -> tuple[str, ...]:
    """The prefix that runs a command as ``uid`` with no rights (util-linux's setpriv;
    the caller must be root), or nothing for None."""
    if uid is None:
        return ()
    return ("setpriv", f"--reuid={uid}", f"--regid={uid}", "--clear-groups", "--inh-caps=-all")


def _note_scheduling(base: str) -> None:
    import httpx

    with contextlib.suppress(httpx.HTTPError, ValueError, KeyError):
        got = httpx.get(base + "api/v1/health", timeout=10).json()["scheduling"]
        SERVER_SCHEDULING.clear()
        SERVER_SCHEDULING.update(got)


@contextlib.contextmanager
def telerobot_process(
    *args: str,
    wait_for: str,
    env: dict[str, str] | None = None,
    timeout: float = 60.0,
    drain: bool = True,
    prefix: tuple[str, ...] = (),
    exe: Path | None = None,
    cwd: Path | None = None,
) -> Iterator[tuple[subprocess.Popen[str], re.Match[str]]]:
    """Run ``telerobot ARGS`` as its own process; yield once a line of its output
    matches ``wait_for`` (the benchmarks and the end-to-end tests use it). ``prefix``
    runs it through another command (``ip netns exec NAME``); ``exe``: another
    installation's ``telerobot`` (default: this environment's), run in ``cwd``."""
    exe = exe or Path(sys.executable).parent / "telerobot"
    proc = subprocess.Popen(
        [*prefix, str(exe), *args],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})},
    )
    assert proc.stdout is not None
    seen: list[str] = []
    deadline = time.monotonic() + timeout
    match = None
    try:
        while match is None:
            line = proc.stdout.readline()
            if not line and proc.poll() is not None:
                raise RuntimeError(f"telerobot {' '.join(args)} exited:\n{''.join(seen)}")
            seen.append(line)
            match = re.search(wait_for, line)
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"no line matching {wait_for!r} within {timeout} s:\n{''.join(seen)}"
                )
        if drain:  # keep reading its output so a chatty server never blocks on a full pipe
            # (BENCH_SERVER_LOG=FILE: kept there, for a closer look at a bench's server)
            threading.Thread(target=_drain, args=(proc, seen), daemon=True).start()
        yield proc, match
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()


def _drain(proc: subprocess.Popen[str], seen: list[str]) -> None:
    path = os.environ.get("BENCH_SERVER_LOG")
    if not path:
        for _ in proc.stdout or []:
            pass
        return
    with open(path, "a") as log:
        log.writelines(seen)
        for line in proc.stdout or []:
            log.write(line)
            log.flush()


SERVED = r"https?://(\S+?):(\d+)/"  # the URL `telerobot serve` prints: host, port


@contextlib.contextmanager
def serve_for_bench(
    *args: str,
    env: dict[str, str] | None = None,
    prefix: tuple[str, ...] = (),
    port: int = 0,
    ready: bool = False,
    exe: Path | None = None,
    cwd: Path | None = None,
    user: int | None = None,
) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """`telerobot serve ARGS` for a benchmark or a test (the one way both start a
    server): this HTTP port (0: any free one, so a running `make run` is never in the
    way), any priority port, a throw-away state folder, no 3D view. With ``ready``, once
    its robot is READY; with ``user``, as that user with no rights (``as_user``). Yields
    the process and its base URL (http://host:port/)."""
    import tempfile

    with tempfile.TemporaryDirectory() as state:
        if user is not None:
            os.chown(state, user, user)
        with telerobot_process(
            "serve", "--http-port", str(port), "--priority-port", "0", "--state-dir", state,
            *args, wait_for=SERVED, env={"TELEROBOT_VIEWER": "false", **(env or {})},
            prefix=(*prefix, *as_user(user)), exe=exe, cwd=cwd,
        ) as (proc, m):  # fmt: skip
            host = "127.0.0.1" if m.group(1) == "localhost" else m.group(1)
            base = f"http://{host}:{m.group(2)}/"
            if ready:
                wait_until_ready(base)
            _note_scheduling(base)
            yield proc, base


def wait_until_ready(base: str, timeout: float = 30.0) -> None:
    """Wait until the server at ``base`` says every arm is READY (the simulated arm
    initialises to its home pose first)."""
    import httpx

    deadline = time.monotonic() + timeout
    while any(
        (status := arm["status"]) != "READY" for arm in httpx.get(base + "api/v1/robot/arms").json()
    ):
        if time.monotonic() > deadline:
            raise RuntimeError(f"the robot never became READY (still {status})")
        time.sleep(0.05)
