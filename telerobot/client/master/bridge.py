"""The master-arm bridge (``telerobot master``), the thesis's MasterArm component.

It runs on the operator's machine, beside the haptic device, and talks to the server
over the priority channel. Every millisecond it reads the device and

- while the clutch is held, adds the handle's motion since the last reading (mapped
  to the robot base and scaled) to an increment, sent as one CART_INC every command
  period: the server applies it through the same lease, limits and dead-man as any
  other input. Releasing the clutch and gripping again re-anchors, so the operator
  can re-centre their hand; a jump larger than ``max_step_m`` is dropped, not sent;
- renders the newest remote force on the device: the sensor's reading rotated into
  the base frame with the arm's reported orientation, then into the device's frame,
  scaled and clamped (switchable);
- adds local impedance compensation f = αv + βa from the device's own motion, so the
  device feels lighter (switchable);
- keeps the rendered force passive (``passivity``: the observer and controller of
  ``telerobot.client.master.passivity``): a delayed, stiff contact cannot push back more energy
  than the operator put in, which is what makes such a loop ring;
- with ``two_port`` (the default), sends its books to the arm (``ENERGY``, every
  command period), which then puts no more energy into a contact than the operator put
  in (``telerobot.server.control.slave_port``), and keeps the handle within what the contact
  gave back (``PORT_ENERGY``). While the clutch is held it sends an increment every
  command period, still or not: the arm catches up with the master on them.

Heartbeats keep the lease while the bridge runs. An optional constant virtual delay
holds each force sample until its sensor time plus T_v (Kosuge's virtual time delay),
so the feedback loop sees one constant delay instead of a jittering one. For tests and
the benchmark, ``delay_rtt_s`` adds a round trip of its own inside the bridge (half on
the commands going out, half on the forces coming in, each with ``delay_jitter_s`` of
normal jitter, kept in order), so a slow link can be had without network namespaces.

When the priority channel goes away (a server restart, a network cut), the device is
let go (no force, clutch re-anchored) and, given a ``reconnect`` function, the bridge
connects again with a doubling backoff (0.5 s … 8 s, from the start after a success).

On a server driving two arms or more (docs/arms.md) the bridge drives one, ``arm``
(the wire's index): its increments and ENERGY name it, and it renders that arm's
forces and reads that arm's STATE only. 0 (the default) is a one-arm server's arm.
"""

from __future__ import annotations

import contextlib
import logging
import math
import random
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from telerobot.client.master.link import PriorityLink, Reply
from telerobot.client.master.passivity import PassivityController, PassivitySettings
from telerobot.drivers.base import (
    FloatArray,
    ForceSample,
    InvalidCommand,
    MasterArm,
    TelerobotError,
)
from telerobot.drivers.master.impedance import ImpedanceCompensator
from telerobot.drivers.threads import WorkerThread
from telerobot.protocol import messages as m

log = logging.getLogger(__name__)

HAND_BACK_S = 0.6  # a clutch that took over from a policy, let go this long, hands back

CONTACT_RAMP_N = 2.0  # remote force over which the contact damper fades in


@dataclass
class BridgeSettings:
    rate_hz: float = 1000.0  # device reads per second
    command_rate_hz: float = 100.0  # CART_INC per second while the clutch is held and moving
    motion_scale: float = 1.0  # robot metres per device metre
    render_force: bool = True
    force_scale: float = 0.05  # device newtons per remote newton (60 N → 3 N)
    compensation: bool = True
    alpha: float = 0.0  # N·s/m: compensates the device's viscous friction
    beta: float = 0.0  # kg: compensates part of its mass
    virtual_delay_s: float = 0.0  # constant delay for force feedback; 0 = render at once
    max_step_m: float = 0.01  # a larger jump between two readings is a tracking glitch
    heartbeat_s: float = 0.05
    passivity: bool = True  # damp the rendered force when the port makes energy
    # …and the arm's side too (the two-port: ENERGY / PORT_ENERGY); only with passivity
    # and rendered forces (without either there is no budget to keep to).
    two_port: bool = True
    # The passivity controller's cap. High, because its damper is energy-bounded (it
    # takes exactly the port's deficit, in bursts, not a standing 1000 N·s/m the device
    # could not render stably at 1 kHz) and the device's own force limit comes first;
    # bench.master_contact: at 200 ms, a cap of 40 left the contact ringing at 0–60 N,
    # 200 at 0–30 N, 1000 settled it.
    max_damping_n_s_m: float = 1000.0
    # A damper on the handle while in contact (N·s/m at the device, faded in over the
    # first CONTACT_RAMP_N of remote force; none in free space): what the delayed loop
    # hand–handle–arm–contact needs beyond passivity, which bounds the energy a contact
    # gives back but not how long a passive exchange of it rings. bench.master_contact
    # in virtual time, the 5 mm/s press: at 200 ms the contact rang at 1.44 N without
    # it, 0.017 N at 5, 0.012 N at 10; at 50 ms 0.14 → 0.016 N; 0, 100, 400 and 700 ms
    # unchanged. 10 N·s/m resists a 2 cm/s motion in contact with 0.2 N.
    contact_damping_n_s_m: float = 10.0
    delay_rtt_s: float = 0.0  # an injected round trip (tests, benchmarks), split in two
    delay_jitter_s: float = 0.0  # σ of the normal jitter on each half, order kept

    def check(self) -> BridgeSettings:
        positive = ("rate_hz", "command_rate_hz")
        for name in (
            *positive, "motion_scale", "force_scale", "alpha", "beta", "contact_damping_n_s_m",
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0) or (name in positive and value <= 0):
                raise InvalidCommand(f"{name} must be a finite number > 0, got {value!r}")
        if not (0 <= self.virtual_delay_s <= 1.0):
            raise InvalidCommand("virtual_delay_s must be between 0 and 1 s")
        if not (0 <= self.delay_rtt_s <= 2.0):  # (NaN fails both)
            raise InvalidCommand(f"delay_rtt_s must be between 0 and 2 s, got {self.delay_rtt_s!r}")
        if not (0 <= self.delay_jitter_s <= 0.5):
            raise InvalidCommand(
                f"delay_jitter_s must be between 0 and 0.5 s, got {self.delay_jitter_s!r}"
            )
        PassivitySettings(max_damping_n_s_m=self.max_damping_n_s_m).check()
        return self


def rotvec(R: FloatArray) -> FloatArray:
    """The rotation vector of a rotation matrix (small and large angles)."""
    angle = math.acos(max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0)))
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 2.0 * math.sin(angle)
    if abs(s) < 1e-9:
        return np.asarray(axis / 2.0, dtype=float)  # ~0 rad (π is out of reach in 1 ms)
    return np.asarray(axis * (angle / s), dtype=float)


class Backoff:
    """Delays between attempts: ``first_s``, doubling up to ``max_s``; reset to the first."""

    def __init__(self, first_s: float = 0.5, max_s: float = 8.0) -> None:
        self.first_s = first_s
        self.max_s = max_s
        self._next = first_s

    def next(self) -> float:
        delay = self._next
        self._next = min(self.max_s, delay * 2)
        return delay

    def reset(self) -> None:
        self._next = self.first_s


class MasterBridge:
    def __init__(
        self,
        device: MasterArm,
        link: PriorityLink,
        settings: BridgeSettings | None = None,
        *,
        time_source: Callable[[], float] = time.monotonic,
        reconnect: Callable[[], PriorityLink] | None = None,
        backoff: Backoff | None = None,
        arm: int = 0,
    ) -> None:
        self.device = device
        self.arm = arm  # the server's arm it drives (ARM's index; 0: the only arm)
        self.link = link
        self.reconnect = reconnect  # a new link to the server; None: stop when it goes
        self.backoff = backoff or Backoff()
        self.reconnects = 0
        self.connected = True
        self.on_reconnect: Callable[[PriorityLink], None] | None = None  # e.g. take control again
        self.settings = (settings or BridgeSettings()).check()
        self.compensator = ImpedanceCompensator(
            self.settings.alpha,
            self.settings.beta,
            enabled=self.settings.compensation,
            max_force_n=device.max_force_n,
        )
        self.passivity = PassivityController(
            PassivitySettings(
                enabled=self.settings.passivity,
                max_damping_n_s_m=self.settings.max_damping_n_s_m,
                handle_mass_kg=getattr(device, "mass_kg", None),
            )
        )
        if self.two_port:  # nothing may be given back before the arm says what it got
            self.passivity.budget = 0.0
        # The injected delay: commands waiting to go out (due, dX, rotvec), bounded (at
        # 100 a second and at most 1 s each way, 100 wait at once).
        self._outbox: deque[tuple[float, FloatArray, FloatArray, tuple[float, float] | None]] = (
            deque(maxlen=1000)
        )
        self._rng = random.Random(0)
        self._last_due = {"out": -math.inf, "in": -math.inf}
        self._now = time_source
        self._lock = threading.Lock()
        self._force: ForceSample | None = None  # the newest sample to render
        self._delayed: deque[tuple[float, ForceSample]] = deque()
        # The arm's PORT_ENERGY (its surroundings' energy back, J, the arm's units) on
        # its way in through the injected delay: (due, e_in), at most one a command.
        self._arm_energy: deque[tuple[float, float]] = deque(maxlen=1000)
        self._tool_rotation: FloatArray = np.eye(3)
        self.flags = 0
        self._anchor: tuple[FloatArray, FloatArray] | None = None  # last (p, R) while clutched
        self._pending_dx = np.zeros(3)
        self._pending_rv = np.zeros(3)
        self._next_command = 0.0
        self._last_heartbeat = 0.0
        self._worker = WorkerThread(self._run, "master-bridge", prompt=True)
        self._stop = self._worker.stopping
        # What happened, for the status line, tests and the benchmark.
        self.ticks = 0
        self.overruns = 0
        self.commands_sent = 0
        self.energy_sent = 0  # ENERGY messages
        self.arm_energy_in = 0.0  # the newest PORT_ENERGY e_in (J, the arm's units)
        self.arm_energy_out = 0.0  # …and e_out: what the arm put into its surroundings
        self.jumps_dropped = 0
        # Supervising a policy (docs/protocol.md, Supervised autonomy; the mode is the
        # link's): a clutch pressed while a policy holds control takes over, and let go
        # for HAND_BACK_S it hands back.
        self.takeovers = 0
        self._clutch_was = False
        self._clutch_took_over = False
        self._let_go_at: float | None = None
        self.forces_received = 0
        self.forces_stale = 0
        self.states_received = 0
        self.last_rendered: FloatArray = np.zeros(3)
        self.last_error: str | None = None
        self.on_sample: Callable[[ForceSample, float], None] | None = None  # benchmarks
        self._attach(link)

    def _attach(self, link: PriorityLink) -> None:
        link.force_arm = self.arm  # its arm's forces only (0: the only arm's)
        link.on_force = self._on_force
        link.on_state = self._on_state
        link.on_reply = self._on_reply

    # ------------------------------------------------------------ from the link's thread
    def _on_force(self, sample: ForceSample, received: float) -> None:
        self.forces_received += 1
        if self.on_sample is not None:
            self.on_sample(sample, received)
        with self._lock:
            newest = self._delayed[-1][1] if self._delayed else self._force
            if newest is not None and sample.seq <= newest.seq:
                self.forces_stale += 1  # newest wins
                return
            due = -math.inf
            if self.settings.virtual_delay_s > 0:
                due = sample.time - self.link.offset + self.settings.virtual_delay_s
            if self.settings.delay_rtt_s > 0:
                due = max(due, self._due("in", received))
            if due > -math.inf:
                self._delayed.append((due, sample))
            else:
                self._force = sample

    def _due(self, way: str, now: float) -> float:
        """When something injected-delayed now arrives: half the round trip, jittered,
        never before what went ahead of it (a link keeps order)."""
        s = self.settings
        delay = max(0.0, s.delay_rtt_s / 2 + self._rng.gauss(0.0, s.delay_jitter_s))
        due = max(now + delay, self._last_due[way])
        self._last_due[way] = due
        return due

    def _on_state(self, fields: dict[str, Any]) -> None:
        if self.arm and int(fields.get("arm", self.arm)) != self.arm:
            return  # another arm's
        R = np.array([[fields[f"r{i}{j}"] for j in range(3)] for i in range(3)], dtype=float)
        with self._lock:
            self._tool_rotation = R
            self.flags = int(fields["flags"])
            self.states_received += 1

    def _on_reply(self, reply: Reply) -> None:
        if reply.name == "PORT_ENERGY":
            e_in, e_out = float(reply.fields["e_in"]), float(reply.fields["e_out"])
            with self._lock:
                self.arm_energy_out = max(self.arm_energy_out, e_out)
                if self.settings.delay_rtt_s > 0:
                    self._arm_energy.append((self._due("in", self._now()), e_in))
                else:
                    self._take_arm_energy(e_in)
            return
        if reply.name == "ERROR":
            self.last_error = reply.text
            log.warning("server: %s", reply.text)

    def _supervise(self, clutch: bool, now: float) -> None:
        """The clutch as a policy's supervisor: pressed while the policy holds control
        (autonomous or paused) it takes over (the server stops the arm where it is and
        needs no force); let go for ``HAND_BACK_S`` after that, it hands back (a quicker
        re-clutch keeps control). Motion starts from the handle's pose at the press."""
        policy_holds = self.link.autonomy in ("autonomous", "paused")
        if clutch and not self._clutch_was and policy_holds and not self.has_control:
            self.link.lease(m.LeaseAction.TAKE)
            self.takeovers += 1
            self._clutch_took_over = True
        self._clutch_was = clutch
        if not self._clutch_took_over:
            return
        if clutch:
            self._let_go_at = None
            return
        if self._let_go_at is None:
            self._let_go_at = now
        elif now - self._let_go_at >= HAND_BACK_S:
            self._clutch_took_over, self._let_go_at = False, None
            if self.has_control:
                self.link.lease(m.LeaseAction.RELEASE)

    def _take_arm_energy(self, e_in: float) -> None:
        """The arm's surroundings gave back ``e_in`` so far: what the handle may be
        given (in the device's units). Called with the lock held."""
        if math.isfinite(e_in) and e_in > self.arm_energy_in:
            self.arm_energy_in = e_in
        self.passivity.budget = self.arm_energy_in / self._arm_per_device

    @property
    def two_port(self) -> bool:
        s = self.settings
        return s.two_port and s.passivity and s.render_force and s.force_scale > 0

    @property
    def _arm_per_device(self) -> float:
        """The arm's joules per joule at the handle: forces scale by ``force_scale`` on
        the way in, motion by ``motion_scale`` on the way out."""
        s = self.settings
        return s.motion_scale / s.force_scale

    @property
    def has_control(self) -> bool:
        return bool(self.flags & m.StateFlags.YOU_HAVE_CONTROL)

    # ------------------------------------------------------------ one device cycle
    def remote_force_device_frame(self, now: float) -> FloatArray:
        """The force to render now (N, the device's frame), before clamping."""
        with self._lock:
            while self._delayed and self._delayed[0][0] <= now:
                self._force = self._delayed.popleft()[1]
            while self._arm_energy and self._arm_energy[0][0] <= now:
                self._take_arm_energy(self._arm_energy.popleft()[1])
            sample, R = self._force, self._tool_rotation
        if sample is None:
            return np.zeros(3)
        f_base = R @ np.asarray(sample.values[:3], dtype=float)  # sensor (tool axes) → base
        return np.asarray(self.device.to_base.T @ f_base * self.settings.force_scale, dtype=float)

    def tick(self) -> None:
        s = self.settings
        state = self.device.read()
        now = state.time
        self.ticks += 1
        # Forces: the remote contact, kept passive, plus the compensation of the device's
        # own dynamics (a local, deliberate push: not part of the observed port).
        force = self.compensator.update(now, state.position)
        velocity, dt = self.passivity.velocity_from(now, state.position)
        if s.render_force:
            remote = self._clamp(self.remote_force_device_frame(now))
            force = force + self._clamp(self.passivity.step(remote, velocity, dt))
            force = force - self._contact_damping(remote) * velocity
        self.last_rendered = force
        self.device.set_force(force)
        self._supervise(state.clutch, now)
        # Motion: increments while the clutch is held.
        if state.clutch:
            if self._anchor is not None:
                p0, R0 = self._anchor
                dp = state.position - p0
                if float(np.linalg.norm(dp)) > s.max_step_m:
                    self.jumps_dropped += 1
                else:
                    to_base = self.device.to_base
                    self._pending_dx += to_base @ dp * s.motion_scale
                    self._pending_rv += to_base @ rotvec(state.rotation @ R0.T) * s.motion_scale
            self._anchor = (state.position, state.rotation)
        else:
            self._anchor = None
            self._pending_dx[:] = 0.0
            self._pending_rv[:] = 0.0
        if now >= self._next_command:
            self._next_command = now + 1.0 / s.command_rate_hz
            moved = bool(np.any(self._pending_dx) or np.any(self._pending_rv))
            two_port = self.two_port
            # Two-port: every period while gripped (the arm catches up on still ones).
            if (moved or (two_port and state.clutch)) and self.has_control:
                energy = self._energy() if two_port else None
                if s.delay_rtt_s > 0:
                    due = self._due("out", now)
                    self._outbox.append(
                        (due, self._pending_dx.copy(), self._pending_rv.copy(), energy)
                    )
                else:
                    self._send_command(self._pending_dx, self._pending_rv, now, energy)
            self._pending_dx[:] = 0.0
            self._pending_rv[:] = 0.0
        while self._outbox and self._outbox[0][0] <= now:
            _, dx_, rv_, energy_ = self._outbox.popleft()
            self._send_command(dx_, rv_, now, energy_)
        if now - self._last_heartbeat >= s.heartbeat_s:
            self.link.heartbeat()
            self._last_heartbeat = now

    def _contact_damping(self, remote: FloatArray) -> float:
        """The contact damper's coefficient now (N·s/m): ``contact_damping_n_s_m`` once
        the remote force reaches ``CONTACT_RAMP_N``, less below it, none in free space;
        at most the handle's mass over the loop's longest recent step (held longer, a
        damper reverses the handle: see PassivitySettings.handle_mass_kg)."""
        s = self.settings
        if s.contact_damping_n_s_m <= 0 or s.force_scale <= 0:
            return 0.0
        share = min(1.0, float(np.linalg.norm(remote)) / (CONTACT_RAMP_N * s.force_scale))
        return self.passivity.held_stable(s.contact_damping_n_s_m * share)

    def _clamp(self, force: FloatArray) -> FloatArray:
        norm = float(np.linalg.norm(force))
        if norm > self.device.max_force_n:
            return np.asarray(force * (self.device.max_force_n / norm), dtype=float)
        return force

    def _energy(self) -> tuple[float, float]:
        """This side's books for ENERGY, in the arm's units."""
        pc, k = self.passivity, self._arm_per_device
        return pc.put_in * k, max(0.0, pc.given) * k

    def _send_command(
        self, dx: FloatArray, rv: FloatArray, now: float, energy: tuple[float, float] | None
    ) -> None:
        # (The arm is named only when there is one to name: a one-arm link, such as
        # bench.master_contact's virtual one, is called as it always was.)
        if energy is not None:  # first: the increment after it may spend it
            if self.arm:
                self.link.energy(*energy, arm=self.arm)
            else:
                self.link.energy(*energy)
            self.energy_sent += 1
        d, r = dx.tolist(), rv.tolist()
        if self.arm:
            self.link.cartesian((d[0], d[1], d[2]), (r[0], r[1], r[2]), arm=self.arm)
        else:
            self.link.cartesian((d[0], d[1], d[2]), (r[0], r[1], r[2]))
        self.commands_sent += 1
        self._last_heartbeat = now  # any command keeps the dead-man satisfied

    # ------------------------------------------------------------ running
    def start(self, take_control: bool = True, take_over: bool = False) -> None:
        self.device.open()
        self.link.ping()
        if take_control:
            self.link.lease(m.LeaseAction.TAKE_OVER if take_over else m.LeaseAction.TAKE)
        self._worker.start()

    def stop(self) -> None:
        self._worker.stop()
        self.device.set_force(np.zeros(3))
        self.device.close()
        if self.has_control and self.connected:
            with contextlib.suppress(OSError):
                self.link.lease(m.LeaseAction.RELEASE)

    def _lost(self, reason: str) -> bool:
        """The link went away: let the device go, then connect again with backoff (until
        stopped); True once a new link is up, False when there is no reconnecting."""
        self.connected = False
        self.last_error = f"the priority channel closed: {reason}"
        log.error("%s", self.last_error)
        self.device.set_force(np.zeros(3))
        with self._lock:
            self._force = None
            self._delayed.clear()
            self._arm_energy.clear()
            self.arm_energy_in = self.arm_energy_out = 0.0
            self.flags = 0  # no control known on a link that is gone
        self._outbox.clear()
        self.passivity.reset()
        self._anchor = None  # the next grip re-anchors: no jump from the gap
        self._pending_dx[:] = 0
        self._pending_rv[:] = 0
        self.link.close()
        if self.reconnect is None:
            return False
        while not self._stop.wait(self.backoff.next()):
            try:
                link = self.reconnect()
            except (TelerobotError, OSError) as exc:
                log.warning("reconnecting: %s", exc)
                continue
            self._attach(link)
            self.link = link
            self.connected = True
            self.reconnects += 1
            self.backoff.reset()
            self.last_error = None
            log.info("reconnected to the priority channel (%d)", self.reconnects)
            link.ping()
            if self.on_reconnect is not None:
                self.on_reconnect(link)
            return True
        return False

    def _run(self) -> None:
        period = 1.0 / self.settings.rate_hz
        next_t = self._now()
        pings = 0
        while not self._stop.is_set():
            next_t += period
            delay = next_t - self._now()
            if delay > 0:
                time.sleep(delay)
            elif delay < -0.05:  # far behind: skip the missed cycles, do not burst
                self.overruns += 1
                next_t = self._now()
            try:
                if self.link.closed_reason is not None:
                    raise OSError(self.link.closed_reason)
                self.tick()
            except OSError as exc:  # the link went away
                if not self._lost(str(exc)):
                    return
                next_t = self._now()
                pings = 0
                continue
            if pings < 5 and self.ticks % 100 == 0:  # a few more for a good clock offset
                self.link.ping()
                pings += 1
