"""``So101Arm``'s settings (``telerobot.drivers.settings``), and where its joint
calibration is kept by default (the leader's is beside it)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pydantic import Field

from telerobot.drivers.settings import DriverSettings


class So101Settings(DriverSettings):
    so101_port: str = Field(
        "/dev/ttyACM0",
        description="the Feetech servo bus: a device path, a pty or socket://host:port"
        " (python -m telerobot.drivers.robot.so101.emulator)",
    )
    so101_baudrate: int = Field(1_000_000, gt=0, description="the bus's baud rate")
    so101_calibration: Path | None = Field(
        None,
        description="the joint calibration file; None: so101-calibration.json in"
        " state_dir, beside the cameras' calibration-<rig>.json",
    )
    so101_reply_timeout: float = Field(
        0.03,
        gt=0,
        le=2.0,
        description="how long a servo has to answer, s (a real bus answers in < 1 ms; an"
        " emulated bus on a loaded machine, a process behind a pty, may need longer)",
    )


CALIBRATION_FILE = "so101-calibration.json"


def default_calibration_path(settings: Mapping[str, Any]) -> Path:
    """``so101-calibration.json`` in the state folder, beside the cameras'
    ``calibration-<rig>.json`` (the folder as the server's ``security.state_dir`` finds
    it: drivers do not import the server)."""
    state = settings.get("state_dir")
    if state is None:
        base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
        state = Path(base) / "telerobot"
    return Path(state) / CALIBRATION_FILE
