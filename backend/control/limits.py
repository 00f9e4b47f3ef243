"""Safety limits the DecisionServer enforces on every command."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from drivers.base import FloatArray, InvalidCommand


@dataclass(frozen=True)
class SafetyLimits:
    # Tool position must stay inside this box (base frame, metres).
    workspace_min: FloatArray = field(default_factory=lambda: np.array([-0.2, -0.8, 0.30]))
    workspace_max: FloatArray = field(default_factory=lambda: np.array([1.05, 0.8, 1.60]))
    max_step_m: float = 0.02  # largest translation one incremental command may ask for
    max_step_rad: float = 0.10  # largest rotation one incremental command may ask for
    max_joint_step_rad: float = 0.10  # largest joint change one incremental command may cause
    max_speed_m_s: float = 0.25  # translation speed of the commanded target
    max_angular_speed_rad_s: float = 1.0
    max_joint_speed_rad_s: float = 1.0  # for joint increments
    force_limit_n: float = 60.0  # contact force that stops motion
    force_release_ratio: float = 0.8  # the force stop clears below this share of the limit
    # A force above contact_force_n marks a contact: for contact_memory_s, moving back
    # toward it goes no faster than contact_speed_m_s. At full speed the arm strikes the
    # surface again before a force stop can act (a master arm bouncing off the simulated
    # block hit it at 7.5 cm/s: 469 N against the 60 N limit, 9.5 mm deep).
    contact_force_n: float = 15.0
    contact_speed_m_s: float = 0.02
    contact_memory_s: float = 2.0
    deadman_timeout_s: float = 0.15  # quiet controller → stop (checked every tick)
    tick_s: float = 0.02  # how often the dead-man is checked

    def __post_init__(self) -> None:
        lo, hi = (
            np.asarray(self.workspace_min, dtype=float),
            np.asarray(self.workspace_max, dtype=float),
        )
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise InvalidCommand("workspace_min must be below workspace_max on every axis")
        for name in (
            "max_step_m",
            "max_step_rad",
            "max_joint_step_rad",
            "max_speed_m_s",
            "max_angular_speed_rad_s",
            "max_joint_speed_rad_s",
            "force_limit_n",
            "contact_force_n",
            "contact_speed_m_s",
            "contact_memory_s",
            "deadman_timeout_s",
            "tick_s",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidCommand(f"{name} must be a positive number, got {v!r}")
        if self.deadman_timeout_s + self.tick_s > 0.2:
            raise InvalidCommand(
                "deadman_timeout_s + tick_s must stay within 0.2 s (motion stops within 200 ms)"
            )

    def in_workspace(self, p: FloatArray, tol: float = 1e-9) -> bool:
        lo, hi = self.workspace_min.tolist(), self.workspace_max.tolist()  # floats: a hot path
        return all(a - tol <= x <= b + tol for x, a, b in zip(p.tolist(), lo, hi, strict=True))
