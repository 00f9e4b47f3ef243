"""Time-domain passivity at the master's port (Ryu & Hannaford 2002; Hannaford & Ryu,
"Time-domain passivity control of haptic interfaces", IEEE T-RA 18(1), 2002).

Seen from the haptic device, everything behind the rendered force (the link with its
delay, the server, the arm, the block) is one port: the device's velocity goes in,
a force comes out. With a stiff contact and a delayed link that port can give back
more energy than the operator put in (the force still pushes after the arm has
already backed off), and the hand-device-arm loop rings or runs away. The passivity
observer adds up the energy that went into the port,

    E(n) = E(n−1) − f(n)·v(n)·Δt      (f: force on the device, v: its velocity),

which is ≥ 0 for anything passive behind it (a spring gives back at most what was
pressed into it). When E goes below zero the port has made energy, and the passivity
controller adds a damper on the device, f ← f − α·v with α = −E / (|v|²·Δt), which
dissipates exactly that deficit in this step (E back to 0), capped at
``max_damping_n_s_m`` (what the device can render without buzzing).

The one-port alone (the first version, still ``two_port=False`` in the bridge and
``--passivity one-port``) needs nothing from the arm and no change to the wire
protocol, and it keeps the handle from being pushed back harder than the hand pushed.
What it cannot do is stop the arm: the increments sent before the force comes back
drive the tool into the surface regardless, which at 400–700 ms (or at 200 ms on a
slower CPU) tripped the force limit, and at 0–50 ms it let the contact ring.

**The two-port**, the default. The same observer
keeps its books split (``put_in``: what the operator put into the link; ``given``:
what the link gave back to them, net of the damper) and sends them to the arm
(``ENERGY``), whose side keeps to them (``telerobot.server.control.slave_port``: the arm puts
into its surroundings no more than the operator has put in). The arm answers with
what its surroundings gave back (``PORT_ENERGY``), and with ``budget`` set the
controller here also keeps ``given`` within that: the handle is pushed back by no
more energy than the contact returned. Each side only needs the other's cumulative
totals, late: no clock sync, and a lost message is made good by the next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand

HOLD_MEMORY = 0.99  # per step: a long step is forgotten over a few hundred
MIN_SPEED_M_S = 1e-4  # slower than this: no damper (α would explode, and nothing moves)


@dataclass
class PassivitySettings:
    enabled: bool = True
    max_damping_n_s_m: float = 1000.0  # the controller's cap on α (BridgeSettings says why)
    # Velocity from successive device positions, low-passed (a real device's encoder
    # steps would otherwise make α jump): first-order filter's cut-off.
    velocity_cutoff_hz: float = 100.0
    # The handle's moving mass (kg; the device says), or None. A damper α held for the
    # loop's step h takes α·h/m of the handle's speed: past 1 it reverses the handle and
    # the damper itself makes energy. At a 1 ms step 1000 N·s/m is safe on a 0.2 kg
    # handle (0.005 of its speed); a busy machine's 20 ms step made it 100 times too
    # strong, and the contact rang. So α ≤ m / h, h the longest recent step.
    handle_mass_kg: float | None = None

    def check(self) -> PassivitySettings:
        for name in ("max_damping_n_s_m", "velocity_cutoff_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InvalidCommand(f"passivity {name} must be a finite number > 0, got {value!r}")
        return self


class PassivityController:
    """The observer and the controller for one device port (3D: forces and velocities
    as vectors, one energy)."""

    def __init__(self, settings: PassivitySettings | None = None) -> None:
        self.settings = (settings or PassivitySettings()).check()
        self.energy = 0.0  # observed: into the port, J (≥ 0 while passive)
        self.put_in = 0.0  # by the operator into the port, J (the arm's budget, scaled)
        self.given = 0.0  # by the port to the operator, net of the damper, J
        # Two-port: what the arm's surroundings gave back into the link, J (device
        # units), as the arm last said; None: one-port (the observer's own books only).
        self.budget: float | None = None
        self.dissipated = 0.0  # by the controller so far, J
        self.generated = 0.0  # most the port ever owed before the controller paid it, J
        self.damping = 0.0  # α of the last step, N·s/m
        self.saturated = 0  # steps where α hit the cap (energy left owed)
        self.velocity: FloatArray = np.zeros(3)
        self._last: tuple[float, FloatArray] | None = None
        self._hold = 0.0  # the longest recent step, s (slowly forgotten)

    def held_stable(self, damping: float) -> float:
        """``damping`` (N·s/m), at most the handle's mass over the loop's longest recent
        step: held longer, a damper reverses the handle (``handle_mass_kg``)."""
        mass = self.settings.handle_mass_kg
        if mass is None or self._hold <= 0:
            return damping
        return min(damping, mass / self._hold)

    def reset(self) -> None:
        """A new contact with the remote side (reconnected): start the books afresh."""
        self.energy = 0.0
        self.put_in = self.given = 0.0
        self.budget = None if self.budget is None else 0.0
        self.damping = 0.0
        self._last = None
        self.velocity = np.zeros(3)

    def velocity_from(self, t: float, position: FloatArray) -> tuple[FloatArray, float]:
        """The device's velocity (filtered) and the step since the last call."""
        p = np.asarray(position, dtype=float)
        if self._last is None:
            self._last = (t, p)
            return self.velocity, 0.0
        t0, p0 = self._last
        dt = t - t0
        self._last = (t, p)
        if dt <= 0:
            return self.velocity, 0.0
        raw = (p - p0) / dt
        a = 1.0 - math.exp(-2 * math.pi * self.settings.velocity_cutoff_hz * dt)
        self.velocity = self.velocity + a * (raw - self.velocity)
        return self.velocity, dt

    def step(self, force: FloatArray, velocity: FloatArray, dt: float) -> FloatArray:
        """The force to put on the device this step: ``force`` (what the port asks),
        plus the damper if the port has made energy. With ``enabled`` off the observer
        still runs (the status line and the benchmark show what it would have done)."""
        f = np.asarray(force, dtype=float)
        v = np.asarray(velocity, dtype=float)
        if dt <= 0:
            return f
        self._hold = max(dt, self._hold * HOLD_MEMORY)
        power = -float(f @ v) * dt  # > 0: the operator pushes energy into the port
        self.energy += power
        if power >= 0:
            self.put_in += power
        else:
            self.given -= power
        self.generated = max(self.generated, -self.energy)
        self.damping = 0.0
        speed2 = float(v @ v)
        owed = self.energy if self.budget is None else min(self.energy, self.budget - self.given)
        if owed >= 0 or speed2 < MIN_SPEED_M_S**2 or not self.settings.enabled:
            return f
        cap = self.held_stable(self.settings.max_damping_n_s_m)
        alpha = -owed / (speed2 * dt)
        if alpha > cap:
            alpha = cap
            self.saturated += 1
        taken = alpha * speed2 * dt
        self.energy += taken
        self.given -= taken
        self.dissipated += taken
        self.damping = alpha
        return f - alpha * v
