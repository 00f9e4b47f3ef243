"""What every PUMA 560 driver shares: ``ModelArm`` with the PUMA's model.

A PUMA driver (the simulation's PUMA, the VAL serial driver) drives this model only:
settings naming another model are refused with what to choose instead.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Self

from telerobot.drivers.base import DriverUnavailable, FloatArray
from telerobot.drivers.clock import Clock
from telerobot.drivers.robot.arm import ArmConfig, ModelArm
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.robot.models import load_model

PUMA_MODEL = "puma560"


@dataclass(frozen=True)
class PumaConfig(ArmConfig):
    """What every PUMA 560 driver reads from the settings (the model must be the PUMA)."""

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Self:
        config = super().from_settings(settings)
        if config.robot_model != PUMA_MODEL:
            raise DriverUnavailable(
                f"this driver drives a PUMA 560, not the {config.model.title}: "
                f"set the robot model to {PUMA_MODEL} or choose the {config.robot_model}'s driver"
            )
        return config


class PumaArm(ModelArm):
    name = "puma560"

    def __init__(
        self,
        *,
        kinematics: ArmKinematics | None = None,
        clock: Clock | None = None,
        home: FloatArray | None = None,
        joint_offsets: FloatArray | None = None,
    ) -> None:
        super().__init__(
            model=load_model(PUMA_MODEL),
            kinematics=kinematics,
            clock=clock,
            home=home,
            joint_offsets=joint_offsets,
        )
