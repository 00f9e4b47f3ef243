"""Start ``telerobot`` commands as real processes for end-to-end tests."""

from __future__ import annotations

import sys
from pathlib import Path

from bench.common import telerobot_process

BIN = Path(sys.executable).parent / "telerobot"
telerobot = telerobot_process
