"""``SimLeader``: a leader arm moved by a scripted hand, for the joint mirror's demo
and tests (``telerobot master --device sim-leader``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Self

import numpy as np

from telerobot.drivers.base import FloatArray
from telerobot.drivers.robot.models import RobotModel, load_model

Hand = Callable[[float], FloatArray]  # time since open → the leader's joints (rad)


def sway(model: RobotModel) -> Hand:
    """From the model's home pose: the first joint swings ±0.4 rad every 8 s and the
    third ±0.2 rad, after a second at rest."""
    home = model.pose(model.home_pose)

    def hand(t: float) -> FloatArray:
        q = home.copy()
        if t > 1.0:
            a = 2 * math.pi * (t - 1.0) / 8.0
            q[0] += 0.4 * math.sin(a)
            q[2] += 0.2 * math.sin(a)
        return np.clip(q, model.qlim[:, 0], model.qlim[:, 1])

    return hand


class SimLeader:
    name = "sim-leader"

    def __init__(
        self,
        model: RobotModel | None = None,
        hand: Hand | None = None,
        *,
        time_source: Callable[[], float] = time.monotonic,
    ) -> None:
        self.model = model or load_model("so101")
        self.joint_names = self.model.joint_names
        self.hand = hand or sway(self.model)
        self._now = time_source
        self._opened = 0.0

    @classmethod
    def from_options(
        cls, model: RobotModel, *, port: str, baudrate: int, calibration: str | None
    ) -> Self:
        return cls(model)  # nothing to open: the scripted hand moves the model's joints

    def open(self) -> None:
        self._opened = self._now()

    def close(self) -> None:
        pass

    def read(self) -> FloatArray:
        return np.asarray(self.hand(self._now() - self._opened), dtype=float)
