"""The OpenCV cameras' settings (``telerobot.drivers.settings``)."""

from __future__ import annotations

from pydantic import Field

from telerobot.drivers.settings import DriverSettings


class OpenCVSettings(DriverSettings):
    camera_devices: list[str] = Field(
        ["0", "1"],
        description="opencv: the left and right cameras; opencv-sbs: the first (an index"
        " or a device path)",
    )
