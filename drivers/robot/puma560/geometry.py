"""The PUMA 560's geometry: its standard DH table, joint limits and named poses, as
Robotics Toolbox for Python's ``Puma560`` has them. Numbers only (no Pinocchio): the
model (``telerobot.drivers.robot.models.puma560``) and a client-only install's joint
mirror read them; ``kinematics`` solves with them."""

from __future__ import annotations

import math
from typing import Final

import numpy as np

from telerobot.drivers.base import FloatArray

PI: Final = math.pi
TWO_PI: Final = 2.0 * math.pi

# d, a, alpha for joints 1..6 (metres, radians)
D1: Final = 0.67183
A2: Final = 0.4318
D3: Final = 0.15005
A3: Final = 0.0203
D4: Final = 0.4318
DH: Final = (
    (D1, 0.0, PI / 2),
    (0.0, A2, 0.0),
    (D3, A3, -PI / 2),
    (D4, 0.0, PI / 2),
    (0.0, 0.0, -PI / 2),
    (0.0, 0.0, 0.0),
)
QLIM_DEG: Final = ((-160, 160), (-45, 225), (-225, 45), (-110, 170), (-100, 100), (-266, 266))
QLIM: Final = np.radians(np.array(QLIM_DEG, dtype=float))  # (6, 2) lower, upper

# Robotics Toolbox's named poses. qn's q3 is written -pi rather than +pi: the same
# arm pose, but +pi lies past q3's upper limit of 45 degrees.
NAMED_POSES: Final[dict[str, FloatArray]] = {
    "qz": np.zeros(6),  # zero angles, upper arm horizontal, forearm up
    "qr": np.array([0.0, PI / 2, -PI / 2, 0.0, 0.0, 0.0]),  # ready: arm straight up
    "qs": np.array([0.0, 0.0, -PI / 2, 0.0, 0.0, 0.0]),  # stretched: arm horizontal
    "qn": np.array([0.0, PI / 4, -PI, 0.0, PI / 4, 0.0]),  # nominal: dextrous, not singular
}
