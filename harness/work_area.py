"""The gripper positions across the simulated work area, 0.45–0.95 m × −0.45–0.35 m ×
0.42–0.75 m above the base (6 × 6 × 4 points): over them bench.ar_registration measures,
and tests/test_calibration.py checks, how far each calibration method's projection
lands from the true camera's."""

from __future__ import annotations

import numpy as np


def work_area() -> np.ndarray:
    return np.array(
        [
            [x, y, z]
            for x in np.linspace(0.45, 0.95, 6)
            for y in np.linspace(-0.45, 0.35, 6)
            for z in np.linspace(0.42, 0.75, 4)
        ]
    )
