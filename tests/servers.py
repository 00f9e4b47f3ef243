"""Start ``telerobot`` commands as real processes for end-to-end tests."""

from __future__ import annotations

import contextlib
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

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
