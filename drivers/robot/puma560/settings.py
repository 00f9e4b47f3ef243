"""``ValSerialPuma``'s settings (``telerobot.drivers.settings``)."""

from __future__ import annotations

from pydantic import Field

from telerobot.drivers.settings import DriverSettings


class ValSerialSettings(DriverSettings):
    serial_port: str = Field(
        "/dev/ttyS0", description="VAL's RS-232 port: a device path, a pty, socket://host:port"
    )
    serial_baudrate: int = Field(9600, gt=0, description="the port's baud rate")
    serial_reply_timeout: float = Field(1.0, gt=0, description="how long VAL has to answer, s")
