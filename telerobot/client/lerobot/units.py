"""LeRobot's units for an arm's joints, one rule for the export and the plugins
(docs/lerobot.md): a dataset exported from a Telerobot recording and the observation
and action of the ``telerobot`` robot plugin are in the same units, LeRobot's own.

- A joint is in **degrees** (LeRobot's ``MotorNormMode.DEGREES``, the SO-101's
  ``use_degrees=True``, its 0.6 default), from the model's zero and direction, which
  for the SO-101 are LeRobot's (``drivers/robot/so101/calibration.py``).
- A joint named ``gripper`` is in **0–100 % of its range** (LeRobot's
  ``RANGE_0_100``): 0 at the model's lower limit, 100 at its upper.

LeRobot's SO-101 degrees are 360/4095 per servo step where the model turns 2π per 4096
steps: ``DEGREE_SCALE`` carries the 0.02 % between them, so an exported value equals
what ``so_follower`` reads from the same servo position. The PUMA 560 (no LeRobot arm)
is in plain degrees.

Needs numpy only: the light client install imports it, and the server's exporter.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

GRIPPER = "gripper"
# The dataset's robot_type per model, as LeRobot 0.6.1's ``lerobot-record`` writes it for
# the arms it knows (its SO-100/101 follower is ``so_follower``); other arms by their
# model's name.
ROBOT_TYPES = {"so101": "so_follower"}
# LeRobot's degrees per model degree, for the arms whose servos it reads itself.
DEGREE_SCALE = {"so101": 4096 / 4095}

FloatArray = npt.NDArray[np.float64]
# Farther than a float32 round trip of a joint in LeRobot's units could move it (its
# degrees, or 0–100 for a gripper, at float32's 2^-24 relative precision): a real clip.
ROUND_TRIP_RAD = 1e-5


def robot_type(model: str) -> str:
    return ROBOT_TYPES.get(model, model)


# LeRobot's two SO-101 followers as one robot (lerobot/robots/bi_so_follower): its
# robot_type, and its arms' names, which prefix each motor's key (left_shoulder_pan.pos).
BIMANUAL_SO = "bi_so_follower"
BIMANUAL_ARMS = ("left", "right")


def is_bimanual_so(arms: Sequence[tuple[str, str]]) -> bool:
    """Two SO-101s named left and right (``(name, model)``): LeRobot's bimanual SO
    follower."""
    return sorted(name for name, _ in arms) == list(BIMANUAL_ARMS) and all(
        model == "so101" for _, model in arms
    )


def dataset_robot_type(arms: Sequence[tuple[str, str]]) -> str:
    """The dataset's ``robot_type`` for these arms (``(name, model)``): one arm's as
    LeRobot names it (``so_follower``); two SO-101s named left and right, LeRobot's
    bimanual ``bi_so_follower``; other arms, theirs joined by ``+``."""
    if len(arms) == 1:
        return robot_type(arms[0][1])
    if is_bimanual_so(arms):
        return BIMANUAL_SO
    return "+".join(robot_type(model) for _, model in arms)


def column_order(arms: Sequence[tuple[str, str]]) -> list[int]:
    """In which order the arms' columns go (indexes into ``arms``): left first for
    LeRobot's bimanual SO follower, whatever order the server has them in; else as
    given. Each arm's keys are then prefixed with its name and ``_`` (one arm: none)."""
    if is_bimanual_so(arms):
        return sorted(range(len(arms)), key=lambda i: BIMANUAL_ARMS.index(arms[i][0]))
    return list(range(len(arms)))


@dataclass(frozen=True)
class JointUnits:
    """The conversion for one arm: its joint names in order and their limits (rad)."""

    model: str
    names: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if len(self.names) != len(self.limits):
            raise ValueError(f"{len(self.names)} joint names for {len(self.limits)} limits")
        for name, (lo, hi) in zip(self.names, self.limits, strict=True):
            if name == GRIPPER and not hi > lo:
                raise ValueError(f"the gripper's range {lo}…{hi} rad is empty")

    @classmethod
    def of(cls, model: str, names: Sequence[str], limits_rad: Any) -> JointUnits:
        lim = tuple((float(lo), float(hi)) for lo, hi in limits_rad)
        return cls(model, tuple(names), lim)

    @classmethod
    def from_described(cls, described: dict[str, Any]) -> JointUnits:
        """From ``GET /api/v1/robot/model`` (its ``joint_limits_deg``)."""
        limits = [(math.radians(lo), math.radians(hi)) for lo, hi in described["joint_limits_deg"]]
        return cls.of(str(described["model"]), described["joint_names"], limits)

    @property
    def robot_type(self) -> str:
        return robot_type(self.model)

    @property
    def feature_names(self) -> list[str]:
        """LeRobot's per-motor keys: ``shoulder_pan.pos`` …"""
        return [f"{name}.pos" for name in self.names]

    def unit(self, name: str) -> str:
        return "% of range" if name == GRIPPER else "deg"

    def describe(self) -> str:
        """In words, for ``meta/info.json`` and the docs."""
        grip = GRIPPER in self.names
        return "degrees" + (", gripper 0–100 % of its range" if grip else "")

    def _scale(self) -> float:
        return math.degrees(1.0) * DEGREE_SCALE.get(self.model, 1.0)

    def to_lerobot(self, q: Any) -> FloatArray:
        """Joint angles (rad; the last axis one per joint) in LeRobot's units."""
        out = np.array(q, dtype=np.float64) * self._scale()
        for i, name in enumerate(self.names):
            if name == GRIPPER:
                lo, hi = self.limits[i]
                out[..., i] = (np.asarray(q, np.float64)[..., i] - lo) / (hi - lo) * 100.0
        return out

    def from_lerobot(self, values: Any) -> FloatArray:
        """LeRobot's units back to joint angles (rad)."""
        v = np.array(values, dtype=np.float64)
        out = v / self._scale()
        for i, name in enumerate(self.names):
            if name == GRIPPER:
                lo, hi = self.limits[i]
                out[..., i] = lo + v[..., i] / 100.0 * (hi - lo)
        return out

    def clip(self, q: FloatArray) -> tuple[FloatArray, list[str]]:
        """``q`` (rad) inside the limits, and the names of the joints it moved by more
        than a float32 round trip does: a dataset stores joints as float32, and a joint
        recorded at its limit reads back up to ~1e-7 of it beyond (no target worth a
        warning)."""
        lo = np.array([a for a, _ in self.limits])
        hi = np.array([b for _, b in self.limits])
        clipped = np.clip(q, lo, hi)
        moved = [
            n for n, a, b in zip(self.names, q, clipped, strict=True) if abs(a - b) > ROUND_TRIP_RAD
        ]
        return clipped, moved
