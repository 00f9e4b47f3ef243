"""Joint motion with velocity and acceleration limits, for simulated arms, and the
arm's controlled stop.

``JointMotion`` tracks a target the way a servo controller does: every joint
accelerates, cruises and brakes within its limits, all joints scaled so they arrive
together, and a new target may arrive at any time (teleoperation retargets the arm
many times a second) without a velocity jump. It is stepped at a fixed ``dt`` on
demand, so its state is a pure function of the time it is advanced to.

Two sets of limits: the *planning* limits (``PUMA_VMAX``, ``PUMA_AMAX``) shape every
commanded motion, smooth on the gears and the payload; the *stop* deceleration
(``PUMA_STOP_DECEL``) is what the drives can brake at, and only a stop uses it
(``JointMotion.brake``, ``StopRamp``). A stop is synchronised: every joint slows
uniformly and all reach rest together, the slowest at its limit, so the tool stops on
the path it was moving along rather than swinging off it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from telerobot.drivers.base import FloatArray

# A PUMA 560 moves its big joints at roughly 1 rad/s and its wrist twice as fast
# (planning limits: what every commanded motion keeps to).
PUMA_VMAX = np.array([1.0, 1.0, 1.0, 2.0, 2.0, 2.0])  # rad/s
PUMA_AMAX = np.array([2.0, 2.0, 2.0, 4.0, 4.0, 4.0])  # rad/s²
# The deceleration of a stop: the drives braking the arm, which takes any joint from
# full speed to rest in 0.1 s. An estimate, to be measured on the real arm (ISO
# 10218-1 asks for stopping time and distance at 33/66/100 % speed, load and reach).
# The drives' peak torques are 97.6, 186.4, 89.4, 24.2, 20.1, 21.3 N·m (Armstrong,
# Khatib & Burdick, ICRA 1986, table 7); the inertia they brake, motors through the
# gears included (joint 1: 200e-6 kg·m² × 62.6² = 0.78 kg·m², Corke & Armstrong-
# Hélouvry, ICRA 1994), is up to about 4 kg·m² on joint 1 with the arm outstretched,
# 4.3 on joint 2, 0.9 on joint 3 and 0.2 on each wrist joint: 25-90 rad/s² on joints
# 1-3 and over 100 rad/s² at the wrist at full torque. A controlled stop keeps torque
# in hand for gravity and a payload: 10 rad/s² (0.4 × the weakest, joint 1) and 20.
PUMA_STOP_DECEL = np.array([10.0, 10.0, 10.0, 20.0, 20.0, 20.0])  # rad/s²
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


# ------------------------------------------------------------------ stopping
def stop_time(velocity: Sequence[float] | FloatArray, decel: FloatArray) -> float:
    """Time a synchronised stop from joint ``velocity`` (rad/s) takes: that of the
    joint slowest to stop at its deceleration limit ``decel`` (rad/s²)."""
    return max(
        (abs(float(v)) / float(d) for v, d in zip(velocity, decel, strict=True)), default=0.0
    )


def stop_distance(velocity: Sequence[float] | FloatArray, decel: FloatArray) -> FloatArray:
    """How far each joint turns (rad) in a synchronised stop from ``velocity``."""
    v = np.asarray(velocity, dtype=float)
    result: FloatArray = v * stop_time(v, decel) / 2.0
    return result


def cartesian_stop(
    jacobian: FloatArray, speed: float, decel: FloatArray, vmax: FloatArray
) -> tuple[float, float]:
    """Time (s) and distance (m) to rest of a stop from tool speed ``speed`` (m/s) in a
    straight line with the orientation held, in the worst direction, at the pose whose
    6×6 geometric ``jacobian`` (rows vx vy vz wx wy wz) is given.

    Joint i turns at ``|row_i(J⁻¹)[:3] · u| · speed`` for direction ``u``, at most
    ``‖row_i(J⁻¹)[:3]‖ · speed`` (u along that row), and never faster than its
    ``vmax``; the stop takes the slowest joint's time at its ``decel``, and the tool,
    slowing uniformly along its path, covers ``speed · time / 2``."""
    inverse = np.linalg.pinv(jacobian)[:, :3]
    rates = np.minimum(np.linalg.norm(inverse, axis=1) * speed, vmax)
    time = stop_time(rates, decel)
    return time, speed * time / 2.0


class StopRamp:
    """A synchronised stop from joint angles ``q0`` moving at ``v0``: every joint
    decelerates uniformly, the slowest to stop at its limit ``decel``, and all reach
    rest together after ``duration`` s at ``end``. Exact at any time (no stepping)."""

    def __init__(
        self,
        q0: Sequence[float] | FloatArray,
        v0: Sequence[float] | FloatArray,
        decel: FloatArray,
    ) -> None:
        self.q0 = [float(x) for x in q0]
        self.v0 = [float(x) for x in v0]
        self.duration = stop_time(self.v0, decel)
        self.end = [q + v * self.duration / 2.0 for q, v in zip(self.q0, self.v0, strict=True)]

    def at(self, t: float) -> tuple[list[float], list[float]]:
        """Joint angles and velocities ``t`` s into the stop."""
        T = self.duration
        if t >= T:
            return list(self.end), [0.0] * len(self.end)
        t = max(t, 0.0)
        # v(t) = v0 (1 - t/T); q(t) = q0 + v0 (t - t²/2T)
        k = 1.0 - t / T
        s = t - t * t / (2.0 * T)
        return (
            [q + v * s for q, v in zip(self.q0, self.v0, strict=True)],
            [v * k for v in self.v0],
        )


class SyncMove:
    """A rest-to-rest joint move from ``q0`` to ``q1`` as a controller runs it (a VAL
    ``MOVE``): every joint follows the slowest joint's trapezoid, scaled to its own
    distance, so all start and arrive together after ``duration`` s."""

    def __init__(
        self,
        q0: Sequence[float] | FloatArray,
        q1: Sequence[float] | FloatArray,
        vmax: FloatArray,
        amax: FloatArray,
    ) -> None:
        self.q0 = np.asarray(q0, dtype=float).copy()
        self.delta = np.asarray(q1, dtype=float) - self.q0
        times = [
            trapezoid_time(float(d), float(v), float(a))
            for d, v, a in zip(self.delta, vmax, amax, strict=True)
        ]
        k = int(np.argmax(times))
        self.duration = times[k]
        distance, v, a = abs(float(self.delta[k])), float(vmax[k]), float(amax[k])
        if distance < _EPS:
            self._t_acc, self._peak, self._distance = 0.0, 0.0, 1.0
            return
        self._distance = distance
        if distance <= v * v / a:  # triangular
            self._t_acc = math.sqrt(distance / a)
            self._peak = a * self._t_acc
        else:
            self._t_acc = v / a
            self._peak = v

    def _progress(self, t: float) -> tuple[float, float]:
        """Share of the move done at ``t`` (0…1) and its rate (1/s)."""
        T, ta, peak, D = self.duration, self._t_acc, self._peak, self._distance
        if t <= 0.0 or T <= 0.0:
            return (1.0 if T <= 0.0 else 0.0), 0.0
        if t >= T:
            return 1.0, 0.0
        a = peak / ta
        if t < ta:
            return 0.5 * a * t * t / D, a * t / D
        if t <= T - ta:
            return (0.5 * peak * ta + peak * (t - ta)) / D, peak / D
        r = T - t
        return 1.0 - 0.5 * a * r * r / D, a * r / D

    def at(self, t: float) -> tuple[FloatArray, FloatArray]:
        """Joint angles and velocities ``t`` s into the move."""
        s, rate = self._progress(t)
        q: FloatArray = self.q0 + self.delta * s
        v: FloatArray = self.delta * rate
        return q, v


class JointMotion:
    def __init__(
        self,
        q0: FloatArray,
        vmax: FloatArray = PUMA_VMAX,
        amax: FloatArray = PUMA_AMAX,
        dt: float = 0.001,
        stop_decel: FloatArray = PUMA_STOP_DECEL,
    ) -> None:
        self.vmax = [float(x) for x in vmax]
        self.amax = [float(x) for x in amax]
        self.stop_decel = np.asarray(stop_decel, dtype=float).copy()
        self.dt = dt
        self._q = [float(x) for x in q0]
        self._v = [0.0] * len(self._q)
        self._target = list(self._q)
        self._vlim = list(self.vmax)
        self._alim = list(self.amax)
        self._stop: StopRamp | None = None  # braking: the stop under way
        self._stopped_for = 0.0  # seconds into it
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

    @property
    def stopping(self) -> bool:
        """A stop (``brake``) is under way."""
        return self._stop is not None

    def set_target(self, target: FloatArray) -> None:
        """Move toward ``target`` from where the joints are, at their speed (a stop
        under way is abandoned: the arm carries on from its current velocity)."""
        self._stop = None
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
        """Stop as fast as the drives allow (a controlled stop): every joint
        decelerates uniformly, the slowest to stop at its ``stop_decel``, and all come
        to rest together on the path they were on. The target becomes that rest."""
        if self._stop is not None:
            return  # already stopping at the limit: a second stop changes nothing
        ramp = StopRamp(self._q, self._v, self.stop_decel)
        self._target = list(ramp.end)
        self._vlim = list(self.vmax)
        self._alim = list(self.amax)
        if ramp.duration <= 0.0:
            self._v = [0.0] * len(self._v)
            self.moving = False
            return
        self._stop, self._stopped_for = ramp, 0.0
        self.moving = True

    def remaining_time(self) -> float:
        if self._stop is not None:
            return max(0.0, self._stop.duration - self._stopped_for)
        return move_duration(
            self._q, self._target, np.array(self._vlim) + _EPS, np.array(self._alim) + _EPS
        )

    def advance(self, duration: float) -> None:
        """Integrate ``duration`` seconds of motion in fixed steps (the last one partial);
        a stop is followed exactly."""
        if self._stop is not None:
            self._stopped_for += max(duration, 0.0)
            if self._stopped_for < self._stop.duration - 1e-12:
                self._q, self._v = self._stop.at(self._stopped_for)
                return
            self._q, self._v = list(self._stop.end), [0.0] * len(self._q)
            self._stop = None
            self.moving = False
            return
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
