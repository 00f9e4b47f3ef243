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

Energy is counted on the commanded targets, when the next increment (or ``ENERGY``)
comes: a move's work is its length against the mean of the force before it and the
force since (the sensor's samples, summed as they come). Before a move, what it would
cost is judged with the contact's stiffness as seen so far (the force's rise per
millimetre into it, the largest of the recent moves, ``stiffness``): pressing ``d``
further against a force ``F`` costs about ``F·d + k·d²/2``, so a long step (a stalled
machine's, a catch-up) is cut to what the budget pays for, not let through on the
force before it. Forces below ``FORCE_FLOOR_N`` (a sensor's offset and noise) count
as free space: no budget is needed there.
"""

from __future__ import annotations

import math

import numpy as np

from drivers.base import FloatArray

FORCE_FLOOR_N = 1.0  # below this the tool is in free space: its motion is not charged
MAX_OWED_M = 0.01  # the most master motion the arm lags behind by; past it, dropped
OWED_FORGET_S = 0.5  # a pause in the master's increments this long: what is owed goes
# The contact's stiffness before one is seen (N/m; a firm surface), and how fast a
# stiffer one seen is forgotten (per increment: half in ~35 increments, 0.35 s).
START_STIFFNESS_N_M = 2.0e4
STIFFNESS_MEMORY = 0.98
MIN_STIFFNESS_N_M = 1.0e3
MIN_PRESS_M = 5e-6  # a move this short into the contact says nothing of its stiffness


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
        self.stiffness = START_STIFFNESS_N_M  # of the contact, as seen lately, N/m
        self._force_now: FloatArray = np.zeros(3)  # base frame, since the last move
        self._pending: tuple[FloatArray, FloatArray] | None = None  # (move, force before)

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

    def _mean_force(self, rotation: FloatArray) -> FloatArray:
        """The mean force on the tool since the last move (the newest sample if none
        came), in the base frame (``rotation``: the tool's); starts a new mean."""
        mean = np.array(self._sum) / self._n if self._n else np.array(self._last)
        self._sum = [0.0, 0.0, 0.0]
        self._n = 0
        return np.asarray(rotation @ mean, dtype=float)

    def settle(self, rotation: FloatArray) -> None:
        """Count the last move's work, now that the force after it is known, and learn
        the contact's stiffness from it. Called before each increment and ENERGY."""
        self._force_now = after = self._mean_force(rotation)
        if self._pending is None:
            return
        dx, before = self._pending
        self._pending = None
        if max(float(np.linalg.norm(before)), float(np.linalg.norm(after))) < FORCE_FLOOR_N:
            return
        work = -float((before + after) @ dx) / 2.0
        if work > 0:
            self.out += work
        else:
            self.given -= work
        magnitude = float(np.linalg.norm(after))
        if magnitude >= FORCE_FLOOR_N:
            normal = after / magnitude
            pressed, rise = -float(dx @ normal), float((after - before) @ normal)
            seen = rise / pressed if pressed > MIN_PRESS_M and rise > 0 else 0.0
            self.stiffness = max(MIN_STIFFNESS_N_M, seen, self.stiffness * STIFFNESS_MEMORY)

    # ------------------------------------------------------------ an increment
    def owed_for(self, now: float) -> FloatArray:
        """What is owed, to add to the increment arriving ``now`` (nothing after a pause)."""
        last, self._last_increment = self._last_increment, now
        if last is None or now - last > OWED_FORGET_S:
            self.dropped_m += float(np.linalg.norm(self.owed))
            self.owed = np.zeros(3)
        return self.owed.copy()

    def forgive(self) -> None:
        """The increment was refused (the force limit, the workspace…): what was owed
        would only be refused again with every later one, so it goes."""
        self.dropped_m += float(np.linalg.norm(self.owed))
        self.owed = np.zeros(3)

    def allow(self, dx: FloatArray) -> FloatArray:
        """The part of the translation ``dx`` (base frame) the budget allows now."""
        force = self._force_now
        magnitude = float(np.linalg.norm(force))
        if magnitude < FORCE_FLOOR_N:
            return dx
        normal = force / magnitude  # the contact pushes the tool along this
        into = -float(dx @ normal)  # > 0: how far dx presses into the contact
        if into <= 0.0:
            return dx
        # The farthest the budget pays for: F·d + k·d²/2 = budget.
        k, budget = self.stiffness, max(0.0, self.budget)
        reach = (math.sqrt(magnitude * magnitude + 2.0 * k * budget) - magnitude) / k
        if into <= reach:
            return dx
        self.held_j += magnitude * (into - reach) + k * (into * into - reach * reach) / 2.0
        return np.asarray(dx + (into - reach) * normal, dtype=float)

    def moved(self, dx: FloatArray, wanted: FloatArray) -> None:
        """The target moved by ``dx`` where the master wanted ``wanted`` (both base
        frame): its work is counted at the next ``settle``; the rest is owed."""
        self._pending = (np.asarray(dx, dtype=float).copy(), self._force_now)
        owed = wanted - dx
        size = float(np.linalg.norm(owed))
        if size > MAX_OWED_M:
            self.dropped_m += size - MAX_OWED_M
            owed = owed * (MAX_OWED_M / size)
        self.owed = owed
