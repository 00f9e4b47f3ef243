"""``SimMaster``: a haptic master device as a mass–damper, moved by a scripted hand.

The hand is a spring and damper pulling the handle toward where a script says the
hand is; the device adds the force the bridge renders; the handle integrates
m·a = F_hand + F_rendered − b·v in steps of at most 1 ms. ``hand_force`` is what
the operator's hand has to push with, so tests can feel what the operator feels
(a lighter arm with impedance compensation, a push back on contact).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from telerobot.drivers.base import FloatArray, MasterState

Hand = Callable[[float], tuple[FloatArray, bool]]  # time since open → (hand position, clutch)


def still_hand(t: float) -> tuple[FloatArray, bool]:
    return np.zeros(3), False


class SimMaster:
    name = "sim-master"

    def __init__(
        self,
        hand: Hand = still_hand,
        *,
        mass_kg: float = 0.2,
        damping_n_s_m: float = 2.0,
        hand_stiffness_n_m: float = 400.0,
        hand_damping_n_s_m: float = 8.0,
        max_force_n: float = 3.3,
        time_source: Callable[[], float] = time.monotonic,
    ) -> None:
        self.hand = hand
        self.mass = self.mass_kg = mass_kg
        self.damping = damping_n_s_m
        self.k_hand = hand_stiffness_n_m
        self.c_hand = hand_damping_n_s_m
        self.max_force_n = max_force_n
        self.to_base: FloatArray = np.eye(3)  # the simulated device is aligned with the base
        self._now = time_source
        self.position = np.zeros(3)
        self.velocity = np.zeros(3)
        self.rendered = np.zeros(3)
        self.hand_force = np.zeros(3)
        self._clutch = False
        self._t0 = 0.0
        self._t = 0.0
        self._hand_prev: FloatArray | None = None

    def open(self) -> None:
        self._t0 = self._t = self._now()
        self.position = np.array(self.hand(0.0)[0], dtype=float)  # the hand holds it
        self.velocity = np.zeros(3)
        self._hand_prev = None

    def close(self) -> None:
        self.rendered = np.zeros(3)

    def set_force(self, force: FloatArray) -> None:
        f = np.asarray(force, dtype=float)
        norm = float(np.linalg.norm(f))
        self.rendered = f * (self.max_force_n / norm) if norm > self.max_force_n else f

    def _step(self, h: float, t: float) -> None:
        target, self._clutch = self.hand(t - self._t0)
        target = np.asarray(target, dtype=float)
        hand_v = np.zeros(3) if self._hand_prev is None else (target - self._hand_prev) / h
        self._hand_prev = target
        self.hand_force = self.k_hand * (target - self.position) + self.c_hand * (
            hand_v - self.velocity
        )
        accel = (self.hand_force + self.rendered - self.damping * self.velocity) / self.mass
        self.velocity = self.velocity + accel * h  # semi-implicit Euler: stable here
        self.position = self.position + self.velocity * h

    def read(self) -> MasterState:
        now = self._now()
        while now - self._t > 1e-9:
            h = min(0.001, now - self._t)
            self._t += h
            self._step(h, self._t)
        return MasterState(now, self.position.copy(), np.eye(3), self._clutch)
