"""What ``SimForceSensor`` (drivers/force/sim.py) reads from the settings."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self


@dataclass(frozen=True)
class SimForceConfig:
    rate_hz: float = 1000.0  # samples per second

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        return cls(rate_hz=float(settings["force_rate_hz"]))
