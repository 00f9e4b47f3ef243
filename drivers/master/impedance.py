"""Local impedance compensation for a master arm (thesis §4.4.2):
f = α·v + β·a from the device's own velocity and acceleration history.

A master arm has friction and inertia of its own, which the operator feels on top
of the remote force. Pushing with α·v cancels viscous friction and β·a cancels part
of the inertia, so the arm feels lighter. v and a are finite differences of the
measured position, each through a first-order low-pass (double differentiation
amplifies sensor noise); β must stay below the device's mass, since the filter's lag
turns more than that into a push the operator cannot hold still.
"""

from __future__ import annotations

import math

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand


class ImpedanceCompensator:
    def __init__(
        self,
        alpha: float = 0.0,
        beta: float = 0.0,
        *,
        cutoff_hz: float = 40.0,
        max_force_n: float = 2.0,
        enabled: bool = True,
    ) -> None:
        for name, value in (("alpha", alpha), ("beta", beta), ("max_force_n", max_force_n)):
            if not (math.isfinite(value) and value >= 0):
                raise InvalidCommand(f"{name} must be a finite number ≥ 0, got {value!r}")
        if not (math.isfinite(cutoff_hz) and cutoff_hz > 0):
            raise InvalidCommand(f"cutoff_hz must be > 0, got {cutoff_hz!r}")
        self.alpha = alpha
        self.beta = beta
        self.cutoff_hz = cutoff_hz
        self.max_force_n = max_force_n
        self.enabled = enabled
        self.velocity = np.zeros(3)
        self.acceleration = np.zeros(3)
        self._last: tuple[float, FloatArray] | None = None

    def reset(self) -> None:
        self._last = None
        self.velocity = np.zeros(3)
        self.acceleration = np.zeros(3)

    def update(self, t: float, position: FloatArray) -> FloatArray:
        """The compensation force (N, the device's frame) for the reading at ``t``."""
        p = np.asarray(position, dtype=float)
        if self._last is not None:
            t0, p0 = self._last
            dt = t - t0
            if dt > 0:
                k = dt / (dt + 1.0 / (2 * math.pi * self.cutoff_hz))
                v = self.velocity + k * ((p - p0) / dt - self.velocity)
                self.acceleration = self.acceleration + k * (
                    (v - self.velocity) / dt - self.acceleration
                )
                self.velocity = v
        self._last = (t, p)
        if not self.enabled:
            return np.zeros(3)
        f = self.alpha * self.velocity + self.beta * self.acceleration
        norm = float(np.linalg.norm(f))
        return f * (self.max_force_n / norm) if norm > self.max_force_n else f
