"""The admittance term of a repeated task (the thesis's "impedance control with the
help of the PUMA and Force Sensor components", ch. 4.3.3, 6.2) on a position-
controlled arm: the commanded pose is offset by the force error over a stiffness,

    B·ẋ + K·x = F_measured − F_recorded      (per chosen base axis)

so in steady state x = (F_measured − F_recorded) / K: pressed harder than when it was
taught, the tool gives way along the force (which points out of the surface); pressed
less, it leans in. The damping B makes it a first-order lag, so a stiff surface does
not make the loop ring (with the surface's stiffness k_e it settles in B / (K + k_e));
the offset's rate and range are limited on top. Pure: the caller supplies dt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand

AXES = "xyz"


@dataclass(frozen=True)
class ComplianceSettings:
    axes: str = "xyz"  # base axes the offset may move along ("" turns it off)
    stiffness_n_per_m: float = 1000.0  # K: 1 N more than taught gives way 1 mm
    damping_n_s_per_m: float = 2000.0  # B: the lag that keeps a stiff contact from ringing
    max_offset_m: float = 0.01  # the offset never exceeds this per axis
    max_rate_m_s: float = 0.02  # nor changes faster than this per axis

    def __post_init__(self) -> None:
        if any(a not in AXES for a in self.axes) or len(set(self.axes)) != len(self.axes):
            raise InvalidCommand(f"compliance axes are some of x, y, z, got {self.axes!r}")
        bounds = {
            "stiffness_n_per_m": (10.0, 1e6),
            "damping_n_s_per_m": (1.0, 1e6),
            "max_offset_m": (0.0, 0.05),
            "max_rate_m_s": (0.0, 0.1),
        }
        for name, (lo, hi) in bounds.items():
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and lo <= v <= hi):
                raise InvalidCommand(f"compliance {name} must be {lo:g}–{hi:g}, got {v!r}")

    @property
    def mask(self) -> FloatArray:
        return np.array([1.0 if a in self.axes else 0.0 for a in AXES])


@dataclass
class Admittance:
    """The offset (base frame, metres) and its law; ``step`` once per control period."""

    settings: ComplianceSettings
    offset: FloatArray = field(default_factory=lambda: np.zeros(3))

    def reset(self) -> None:
        self.offset = np.zeros(3)

    def step(self, measured: FloatArray, recorded: FloatArray, dt: float) -> FloatArray:
        """Advance the offset by ``dt`` seconds given the measured and the recorded
        contact force (base frame, N); returns the new offset."""
        s = self.settings
        if dt <= 0 or not math.isfinite(dt):
            return self.offset.copy()
        error = np.asarray(measured, dtype=float) - np.asarray(recorded, dtype=float)
        if not np.all(np.isfinite(error)):
            error = np.zeros(3)  # a bad sample moves nothing
        rate = (error - s.stiffness_n_per_m * self.offset) / s.damping_n_s_per_m
        # One step never overshoots the steady offset: for a large dt, go there directly.
        target = error / s.stiffness_n_per_m
        step = rate * dt
        beyond = np.abs(step) > np.abs(target - self.offset)
        step = np.where(beyond, target - self.offset, step)
        step = np.clip(step, -s.max_rate_m_s * dt, s.max_rate_m_s * dt)
        offset = np.clip(self.offset + step * s.mask, -s.max_offset_m, s.max_offset_m)
        self.offset = offset * s.mask
        return self.offset.copy()
