"""The arm's side of a master arm's two-port passivity (time-domain passivity, two-port:
Ryu, Artigas & Preusche, "A passivity-based approach for stable haptic teleoperation
with time delay", and Artigas et al.'s position–force two-port), and the master's
motion the arm still owes it.

A master arm (``telerobot master``) sends its motion as increments and gets the
sensor's force back; with a delay, the increments sent before the force returns drive
the tool into the surface blind (at 400 ms a 5 mm/s press is 2 mm into a 5·10⁴ N/m
block: 100 N, past the force limit), and the master's own passivity controller (its
side of the port, ``backend.master.passivity``) can only damp the handle, not the
arm. So the arm keeps its own books:

- The master says, with every ``ENERGY`` message, how much energy its operator has put
  into the link so far (``e_in``, in the arm's units: N·m). That is the arm's
  **budget**: it may put into its surroundings (``out``: the tool pushing against the
  contact force) no more than the master has put in. Energy the surroundings give
  back (``given``: the contact pushing the tool away) goes the other way and is sent to
  the master in ``PORT_ENERGY``, the master's budget for what it renders.
- When an increment would push into the contact past the budget, the part of it into
  the contact is held back (``allow``): the arm stops at the surface until the operator
  presses on the force they feel, which is what puts energy in. Motion along the
  surface and away from it is never held back.
- What was held back, by this rule or by the slow approach after a contact (the
  contact-speed rule), is **owed** (``owed``): it is added to the master's next
  increments, within the same limits, so the arm catches up with the master when the
  budget allows, instead of drifting away from it (the ratchet: moves toward a contact
  slowed, moves away not, and the arm ends off the block). What is owed is bounded
  (``MAX_OWED_M``) and forgotten after a pause in the master's increments
  (``OWED_FORGET_S``: the operator let go of the clutch and re-centred).

Energy is counted on the commanded targets, with the mean contact force since the
last increment (the force sensor's samples, summed as they come): a stiff contact
makes the force follow the target within a millisecond or two, and counting on the
target lets the rule act before the arm has moved. Forces below ``FORCE_FLOOR_N``
(a sensor's offset and noise) count as free space: no budget is needed there.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.base import FloatArray

FORCE_FLOOR_N = 1.0  # below this the tool is in free space: its motion is not charged
MAX_OWED_M = 0.01  # the most master motion the arm lags behind by; past it, dropped
OWED_FORGET_S = 0.5  # a pause in the master's increments this long: what is owed goes


class SlavePort:
    """One master client's port at the arm (base frame, SI units)."""

    def __init__(self) -> None:
        self.master_in = 0.0  # what the master says its operator put in so far, J
        self.master_out = 0.0  # and what it gave back to them, J (shown, not used)
        self.out = 0.0  # what the arm put into its surroundings so far, J
        self.given = 0.0  # what the surroundings gave back into the link so far, J
        self.held_j = 0.0  # energy the held-back motion would have cost, J (shown)
        self.owed: FloatArray = np.zeros(3)  # master motion not yet made, m
        self.dropped_m = 0.0  # owed motion forgotten or past MAX_OWED_M, m
        # The contact force since the last increment, summed in the sensor's frame as
        # the samples come (1 kHz: plain floats), rotated to the base when asked.
        self._sum = [0.0, 0.0, 0.0]
        self._n = 0
        self._last = (0.0, 0.0, 0.0)
        self._last_increment: float | None = None

    # ------------------------------------------------------------ what comes in
    def master_energy(self, e_in: float, e_out: float) -> None:
        """The master's books (cumulative: the newest is the largest; a reordered or
        repeated message changes nothing)."""
        if math.isfinite(e_in) and e_in > self.master_in:
            self.master_in = e_in
        if math.isfinite(e_out) and e_out > self.master_out:
            self.master_out = e_out

    def add_force(self, fx: float, fy: float, fz: float) -> None:
        """One force sample (the force on the tool, the sensor's frame)."""
        s = self._sum
        s[0] += fx
        s[1] += fy
        s[2] += fz
        self._n += 1
        self._last = (fx, fy, fz)

    @property
    def budget(self) -> float:
        """What the arm may still put into its surroundings, J."""
        return self.master_in - self.out

    def contact_force(self, rotation: FloatArray) -> FloatArray:
        """The mean force on the tool since the last increment (the newest sample if
        none came), in the base frame (``rotation``: the tool's)."""
        mean = np.array(self._sum) / self._n if self._n else np.array(self._last)
        return np.asarray(rotation @ mean, dtype=float)

    # ------------------------------------------------------------ an increment
    def owed_for(self, now: float) -> FloatArray:
        """What is owed, to add to the increment arriving ``now`` (nothing after a pause)."""
        last, self._last_increment = self._last_increment, now
        if last is None or now - last > OWED_FORGET_S:
            self.dropped_m += float(np.linalg.norm(self.owed))
            self.owed = np.zeros(3)
        return self.owed.copy()

    def allow(self, dx: FloatArray, rotation: FloatArray) -> FloatArray:
        """The part of the translation ``dx`` (base frame) the budget allows now."""
        force = self.contact_force(rotation)
        magnitude = float(np.linalg.norm(force))
        if magnitude < FORCE_FLOOR_N:
            return dx
        cost = -float(force @ dx)  # > 0: the tool pushes against the contact force
        if cost <= 0.0 or cost <= self.budget:
            return dx
        normal = force / magnitude  # the contact pushes the tool along this
        into = float(dx @ normal)  # < 0: the part of dx into the contact
        share = max(0.0, self.budget) / cost
        held = (1.0 - share) * into * normal
        self.held_j += (1.0 - share) * cost
        return np.asarray(dx - held, dtype=float)

    def moved(self, dx: FloatArray, wanted: FloatArray, rotation: FloatArray) -> None:
        """The target moved by ``dx`` where the master wanted ``wanted`` (both base
        frame): count its energy against the contact force, and owe the rest."""
        force = self.contact_force(rotation)
        if float(np.linalg.norm(force)) >= FORCE_FLOOR_N:
            work = -float(force @ dx)
            if work > 0:
                self.out += work
            else:
                self.given -= work
        self._sum = [0.0, 0.0, 0.0]
        self._n = 0
        owed = wanted - dx
        size = float(np.linalg.norm(owed))
        if size > MAX_OWED_M:
            self.dropped_m += size - MAX_OWED_M
            owed = owed * (MAX_OWED_M / size)
        self.owed = owed
