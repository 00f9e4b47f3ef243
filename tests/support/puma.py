"""PUMA 560 poses the force and contact tests need."""

from __future__ import annotations

import numpy as np

from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)

TOOL = tool_transform(0.1)
DOWN = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])  # tool z pointing down


def joints_with_tip_at(point: np.ndarray) -> np.ndarray:
    kin = Puma560Kinematics(TOOL)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = DOWN, point
    return kin.ik(T, NAMED_POSES["qn"])
