"""Joint motion with velocity and acceleration limits, for simulated arms.

``JointMotion`` tracks a target the way a servo controller does: every joint
accelerates, cruises and brakes within its limits, all joints scaled so they arrive
together, and a new target may arrive at any time (teleoperation retargets the arm
many times a second) without a velocity jump. It is stepped at a fixed ``dt`` on
demand, so its state is a pure function of the time it is advanced to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from drivers.base import FloatArray

# A PUMA 560 moves its big joints at roughly 1 rad/s and its wrist twice as fast.
PUMA_VMAX = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])  # rad/s
PUMA_AMAX = np.array([2.0, 2.0, 2.0, 4.0, 4.0, 4.0])  # rad/s²
_EPS = 1e-12


def trapezoid_time(distance: float, vmax: float, amax: float) -> float:
    """Shortest time to move ``distance`` from rest to rest."""
    d = abs(distance)
    if d < _EPS:
        return 0.0
    if d <= vmax * vmax / amax:  # triangular: never reaches vmax
        return 2.0 * math.sqrt(d / amax)
    return d / vmax + vmax / amax


def move_duration(
    q0: Sequence[float] | FloatArray,
    q1: Sequence[float] | FloatArray,
    vmax: FloatArray,
    amax: FloatArray,
) -> float:
    """Time of a synchronised rest-to-rest joint move: that of its slowest joint."""
    return max(
        (
            trapezoid_time(b - a, float(v), float(ac))
            for a, b, v, ac in zip(q0, q1, vmax, amax, strict=True)
        ),
        default=0.0,
    )


class JointMotion:
    def __init__(
        self,
        q0: FloatArray,
        vmax: FloatArray = PUMA_VMAX,
        amax: FloatArray = PUMA_AMAX,
        dt: float = 0.001,
    ) -> None:
        self.vmax = [float(x) for x in vmax]
        self.amax = [float(x) for x in amax]
        self.dt = dt
        self._q = [float(x) for x in q0]
        self._v = [0.0] * len(self._q)
        self._target = list(self._q)
        self._vlim = list(self.vmax)
        self._alim = list(self.amax)
        self.moving = False

    @property
    def q(self) -> FloatArray:
        return np.array(self._q)

    @property
    def v(self) -> FloatArray:
        return np.array(self._v)

    @property
    def target(self) -> FloatArray:
        return np.array(self._target)

    def set_target(self, target: FloatArray) -> None:
        self._target = [float(x) for x in target]
        err = [abs(t - q) for t, q in zip(self._target, self._q, strict=True)]
        # Scale every joint's limits by its share of the move so all arrive together.
        vel_scale = min(
            (v / e for v, e in zip(self.vmax, err, strict=True) if e > _EPS), default=0.0
        )
        acc_scale = min(
            (a / e for a, e in zip(self.amax, err, strict=True) if e > _EPS), default=0.0
        )
        self._vlim = [min(v, e * vel_scale) for v, e in zip(self.vmax, err, strict=True)]
        self._alim = [min(a, e * acc_scale) for a, e in zip(self.amax, err, strict=True)]
        self.moving = True

    def brake(self) -> None:
        """Stop as fast as the joints allow: retarget each to where it can come to rest."""
        self._target = [
            q + v * abs(v) / (2.0 * a) for q, v, a in zip(self._q, self._v, self.amax, strict=True)
        ]
        self._vlim = list(self.vmax)
        self._alim = list(self.amax)
        self.moving = any(abs(v) > 0 for v in self._v)
        if not self.moving:
            self._target = list(self._q)

    def remaining_time(self) -> float:
        return move_duration(
            self._q, self._target, np.array(self._vlim) + _EPS, np.array(self._alim) + _EPS
        )

    def advance(self, duration: float) -> None:
        """Integrate ``duration`` seconds of motion in fixed steps (the last one partial)."""
        while self.moving and duration > 1e-12:
            h = min(self.dt, duration)
            self._step(h)
            duration -= h

    def _step(self, h: float) -> None:
        done = True
        q, v, tgt = self._q, self._v, self._target
        for i in range(len(q)):
            e = tgt[i] - q[i]
            vi = v[i]
            a_brake = self.amax[i]
            if abs(e) < 1e-10 and abs(vi) <= a_brake * h:
                q[i], v[i] = tgt[i], 0.0
                continue
            done = False
            alim = max(self._alim[i], 1e-9)
            speed = min(self._vlim[i], math.sqrt(2.0 * alim * abs(e)), abs(e) / h)
            v_des = math.copysign(speed, e)
            accelerating = v_des * vi >= 0 and abs(v_des) > abs(vi)
            a = alim if accelerating else a_brake
            dv = max(-a * h, min(a * h, v_des - vi))
            vi += dv
            q[i] += vi * h
            v[i] = vi
        if done:
            self.moving = False
