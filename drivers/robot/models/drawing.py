"""An arm drawn from its model: the URDF's primitive links (cylinders between the
joints) placed in the base frame at given joints, for the simulated cameras and the
3D view. Any model, the same drawing the page makes from the URDF."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray
from telerobot.drivers.robot.models import RobotModel


class ArmDrawing:
    """Not thread-safe (one Pinocchio ``Data``): each drawing thread makes its own."""

    def __init__(self, model: RobotModel) -> None:
        self._model = pin.buildModelFromXML(model.urdf)
        self._data = self._model.createData()
        segments = model.segments
        self._frames = [self._model.getFrameId(s.link) for s in segments]
        self._ends = np.array([[(*s.start, 1.0), (*s.end, 1.0)] for s in segments]).reshape(
            len(segments), 2, 4
        )
        self.radii = np.array([s.radius for s in segments])

    def segments(self, q: FloatArray) -> FloatArray:
        """Each link cylinder's two ends in the base frame at joints ``q`` (N × 2 × 3)."""
        pin.framesForwardKinematics(self._model, self._data, q)
        out = np.empty((len(self._frames), 2, 3))
        for i, fid in enumerate(self._frames):
            out[i] = (self._ends[i] @ self._data.oMf[fid].homogeneous.T)[:, :3]
        return out
