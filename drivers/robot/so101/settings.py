"""``So101Arm``'s settings (``telerobot.drivers.settings``)."""

from __future__ import annotations

from pathlib import Path

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
