"""``NetFtSensor``'s settings (``telerobot.drivers.settings``)."""

from __future__ import annotations

from pydantic import Field

from telerobot.drivers.settings import DriverSettings


class NetFtSettings(DriverSettings):
    netft_address: str = Field(
        "192.168.1.1:49152", description="the sensor's address, HOST or HOST:PORT"
    )
    netft_counts_per_force: float = Field(
        1_000_000.0, gt=0, description="its calibration (from its web page): counts per N"
    )
    netft_counts_per_torque: float = Field(
        1_000_000.0, gt=0, description="counts per N·m (from its web page)"
    )
