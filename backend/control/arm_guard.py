"""One arm as the DecisionServer keeps it safe (docs/arms.md).

A server drives one arm or more. What belongs to each arm is here: its driver, its
model, its limits (workspace box, steps, speeds, force limit, contact rule), its force
sensor and what that sensor last said, and the lock that lets one command at a time
reach its driver. What is shared by every arm stays in the DecisionServer: the clients,
the one operator lease, the e-stop, the dead-man and the supervision of a policy. So a
force stop or a fault on one arm stops that arm alone, while the e-stop, the dead-man
and a lease lost stop them all.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from telerobot.drivers.base import FloatArray, ForceSensor, Robot
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.server.control.limits import SafetyLimits


@dataclass(eq=False)
class ArmGuard:
    name: str  # left, right… ("arm" on a one-arm server)
    index: int  # on the wire: 1 for the first arm (0 there means "the only arm")
    robot: Robot
    kinematics: ArmKinematics  # the DecisionServer's own (Pinocchio data is per instance)
    limits: SafetyLimits
    force: ForceSensor | None = None
    # Where its base stands in the workcell (4×4); commands and its state are in its
    # own base frame, so this is only for what draws or records the arms together.
    mount: FloatArray = field(default_factory=lambda: np.eye(4))
    force_limited: bool = False
    force_base: FloatArray = field(default_factory=lambda: np.zeros(3))  # base frame
    contact_at: float | None = None  # when a contact force was last felt
    contact_sensor: tuple[float, float, float] = (0.0, 0.0, 0.0)  # and that force
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)  # one command at a time
    unsubscribe: Callable[[], None] | None = None

    @property
    def dof(self) -> int:
        return len(self.kinematics.qlim)

    def said(self, text: str, arms: int) -> str:
        """``text`` about this arm, named when the server drives more than one."""
        return text if arms == 1 else f"{self.name}: {text}"


def arm_sensors(
    arms: Sequence[ArmGuard], first: ForceSensor | None
) -> list[tuple[int, ForceSensor]]:
    """Every arm's force sensor with the arm's wire index, the first arm's being
    ``first`` (the one a transport was given: a test's may differ from the arm's own);
    arms with no sensor left out."""
    sensors = [(1, first), *((guard.index, guard.force) for guard in arms[1:])]
    return [(index, sensor) for index, sensor in sensors if sensor is not None]
