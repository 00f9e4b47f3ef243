"""The arm's side of a master arm's two-port passivity (time-domain passivity, two-port:
Ryu, Artigas & Preusche, "A passivity-based approach for stable haptic teleoperation
with time delay", and Artigas et al.'s position–force two-port), and the master's
motion the arm still owes it.

A master arm (``telerobot master``) sends its motion as increments and gets the
sensor's force back; with a delay, the increments sent before the force returns drive
the tool into the surface blind (at 400 ms a 5 mm/s press is 2 mm into a 5·10⁴ N/m
block: 100 N, past the force limit), and the master's own passivity controller (its
side of the port, ``telerobot.client.master.passivity``) can only damp the handle, not the
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

Energy is counted where it flows: at every force sample, the force on the tool times
how far the tool *measured* moved since the last sample (the arm's reported pose, not
its target). Counted on the targets it was not: on a busy machine the arm lags its
target, so a target moving in was charged against the force before the arm got there
(too little) and one moving out against the force still pressing (too much given
back), and the books made energy out of the lag. Before a move, what it would cost is
judged from the target: the part of it already ahead of the measured tool into the
contact (``lead``) is spent as it arrives, and pressing ``d`` further against a force
``F`` costs about ``F·d + k·d²/2``, with ``k`` the contact's stiffness as seen lately
(the force's rise per metre the tool moved into it, the largest recent one,
``stiffness``). So a long step (a stalled machine's, a catch-up) is cut to what the
budget pays for. Forces below ``FORCE_FLOOR_N`` (a sensor's offset and noise) count as
free space: no budget is needed there.
"""

from __future__ import annotations

import math

import numpy as np

from telerobot.drivers.base import FloatArray

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
        self.stiffness = START_STIFFNESS_N_M  # of the contact, as seen lately, N/m
        self._last_increment: float | None = None
        # The newest sample: (force, tool position), base frame; plain floats (1 kHz).
        self._sample: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        # The force and position since the last increment, summed, for its mean.
        self._sum = [0.0] * 6
        self._n = 0
        self._mark: tuple[FloatArray, FloatArray] | None = None  # (force, position) then

    # ------------------------------------------------------------ what comes in
    def master_energy(self, e_in: float, e_out: float) -> None:
        """The master's books (cumulative: the newest is the largest; a reordered or
        repeated message changes nothing)."""
        if math.isfinite(e_in) and e_in > self.master_in:
            self.master_in = e_in
        if math.isfinite(e_out) and e_out > self.master_out:
            self.master_out = e_out

    def add_sample(self, force: FloatArray, position: FloatArray) -> None:
        """One force sample: the force on the tool and where the tool measured was, base
        frame. Counts the work done since the previous sample (trapezoid)."""
        fx, fy, fz = float(force[0]), float(force[1]), float(force[2])
        px, py, pz = float(position[0]), float(position[1]), float(position[2])
        last = self._sample
        self._sample = ((fx, fy, fz), (px, py, pz))
        s = self._sum
        s[0] += fx
        s[1] += fy
        s[2] += fz
        s[3] += px
        s[4] += py
        s[5] += pz
        self._n += 1
        if last is None:
            return
        (gx, gy, gz), (qx, qy, qz) = last
        if max(fx * fx + fy * fy + fz * fz, gx * gx + gy * gy + gz * gz) < FORCE_FLOOR_N**2:
            return  # free space
        work = -0.5 * ((fx + gx) * (px - qx) + (fy + gy) * (py - qy) + (fz + gz) * (pz - qz))
        if work > 0:
            self.out += work
        else:
            self.given -= work

    @property
    def budget(self) -> float:
        """What the arm may still put into its surroundings, J."""
        return self.master_in - self.out

    def settle(self) -> None:
        """Before an increment: the mean force and position since the last one, and the
        contact's stiffness from how the force rose as the tool moved in."""
        if self._n:
            s, n = self._sum, self._n
            mark = (np.array(s[:3]) / n, np.array(s[3:]) / n)
        elif self._sample is not None:
            mark = (np.array(self._sample[0]), np.array(self._sample[1]))
        else:
            return
        self._sum = [0.0] * 6
        self._n = 0
        before, self._mark = self._mark, mark
        force, position = mark
        magnitude = float(np.linalg.norm(force))
        if before is None or magnitude < FORCE_FLOOR_N:
            return
        normal = force / magnitude
        pressed = -float((position - before[1]) @ normal)
        rise = float((force - before[0]) @ normal)
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

    def allow(self, dx: FloatArray, target: FloatArray) -> FloatArray:
        """The part of the translation ``dx`` (base frame) from the target position
        ``target`` that the budget allows now."""
        if self._mark is None:
            return dx
        force, position = self._mark
        magnitude = float(np.linalg.norm(force))
        if magnitude < FORCE_FLOOR_N:
            return dx
        normal = force / magnitude  # the contact pushes the tool along this
        into = -float(dx @ normal)  # > 0: how far dx presses into the contact
        if into <= 0.0:
            return dx
        k = self.stiffness
        # The target already ahead of the tool into the contact: spent as the arm gets
        # there, at a force rising by k per metre.
        lead = max(0.0, -float((target - position) @ normal))
        left = self.budget - (magnitude * lead + k * lead * lead / 2.0)
        ahead = magnitude + k * lead  # the force at the target
        reach = 0.0
        if left > 0:
            reach = (math.sqrt(ahead * ahead + 2.0 * k * left) - ahead) / k
        if into <= reach:
            return dx
        self.held_j += ahead * (into - reach) + k * (into * into - reach * reach) / 2.0
        return np.asarray(dx + (into - reach) * normal, dtype=float)

    def moved(self, dx: FloatArray, wanted: FloatArray) -> None:
        """The target moved by ``dx`` where the master wanted ``wanted`` (both base
        frame): the rest is owed (bounded)."""
        owed = wanted - dx
        size = float(np.linalg.norm(owed))
        if size > MAX_OWED_M:
            self.dropped_m += size - MAX_OWED_M
            owed = owed * (MAX_OWED_M / size)
        self.owed = owed
