"""``SimForceSensor``: a 6-axis wrist sensor on the simulated arm.

It reads the simulated workcell: when the gripper tip is pushed into the table or
the block it feels a contact force (a spring of the obstacle's stiffness, a damper
on the approach speed, a little noise), so what the operator does is what the
sensor feels. Readings are in the sensor frame: origin at the flange, axes of the
tool frame; torques are about the flange.

Sampling runs in its own thread on an absolute schedule (no drift); subscribers are
called from that thread.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from typing import Any, Self

import numpy as np

from telerobot.drivers.base import ArmSnapshot, DeviceContext, ForceSample
from telerobot.drivers.force.config_sim import SimForceConfig
from telerobot.drivers.force.pipeline import Six
from telerobot.drivers.force.sampled import SampledForceSensor
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.drivers.sim.workcell import Workcell

log = logging.getLogger(__name__)

MAX_EXTRAPOLATION = 0.05  # s: the arm publishes its state at least every 20 ms while moving


# Behind by more than this, the slots missed are skipped (and their numbers with them)
# rather than taken at once.
MAX_CATCH_UP_S = 0.1


class SimForceSensor(SampledForceSensor):
    name = "sim-force"
    thread_name = "sim-force-sensor"

    def __init__(
        self,
        workcell: Workcell,
        probe: Callable[[], ArmSnapshot],
        kinematics: ArmKinematics,
        *,
        rate_hz: float = 1000.0,
        noise_n: float = 0.02,
        seed: int = 0,
        time_source: Callable[[], float] = time.monotonic,
        phase: float = 0.0,
    ) -> None:
        """``phase``: where in each period the samples are taken (a share of it, on the
        clock's own grid of periods), so two arms' sensors take turns."""
        self.phase = phase % 1.0
        self.workcell = workcell
        self.probe = probe
        self.kinematics = kinematics  # this sensor's own: Pinocchio data is not thread-safe
        self.noise_n = noise_n
        self._rng = np.random.default_rng(seed)
        self._now = time_source
        super().__init__(rate_hz)
        self._seq = 0
        self.overruns = 0  # samples whose slot had already passed (the thread was late)
        self._boxes = [(b, b.lower.tolist(), b.upper.tolist()) for b in workcell.obstacles]
        # The tip in the flange frame; the tool's rotation is the sensor's frame too, so
        # the offset is expressed in tool axes: R_toolᵀ p_tool.
        tool = kinematics.tool
        self._tool_offset = (tool[:3, :3].T @ tool[:3, 3]).tolist()

    @property
    def counters(self) -> Mapping[str, int]:
        """Samples lost to a stalled thread (skipped in the sequence): GET /force."""
        return {"lost": self.overruns}

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any], context: DeviceContext) -> Self:
        """Feels the arm the context follows in the context's workcell."""
        config = SimForceConfig.from_settings(settings)
        return cls(
            context.workcell(),
            context.arm_probe,
            context.kinematics(),
            rate_hz=config.rate_hz,
            phase=context.sample_phase,
        )

    # ------------------------------------------------------------ physics
    def read_raw(self, t: float) -> Six:
        """Contact force and torque at time ``t`` (no filter, tare or threshold).

        Runs 1000 times a second beside the event loop, holding the GIL: plain floats
        and a broad-phase box test keep free-space samples to a few microseconds."""
        snap = self.probe()
        dt = min(max(t - snap.time, 0.0), MAX_EXTRAPOLATION)
        q = snap.joints + snap.velocities * dt if dt > 0.0 else snap.joints
        (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz) = self.kinematics.fk(q)[
            :3
        ].tolist()
        fx = fy = fz = 0.0
        for box, (lx, ly, lz), (hx, hy, hz) in self._boxes:
            if not (lx < px < hx and ly < py < hy and lz < pz < hz):
                continue  # broad phase: the tip is not inside this box
            depth, normal = box.penetration(np.array([px, py, pz]))
            v_tip = (self.kinematics.jacobian(q) @ snap.velocities)[:3]
            push = max(
                box.stiffness * depth - box.damping * float(v_tip @ normal), 0.0
            )  # never pulls
            fx, fy, fz = fx + push * normal[0], fy + push * normal[1], fz + push * normal[2]
        if self.noise_n > 0:
            nx, ny, nz = self._rng.normal(0.0, self.noise_n, 3).tolist()
            fx, fy, fz = fx + nx, fy + ny, fz + nz
        # Sensor frame = tool axes at the flange: F_s = Rᵀ F; the force acts at the tip,
        # which sits at `tool_offset` (tool frame) from the flange, so τ_s = offset × F_s.
        sx = r00 * fx + r10 * fy + r20 * fz
        sy = r01 * fx + r11 * fy + r21 * fz
        sz = r02 * fx + r12 * fy + r22 * fz
        ox, oy, oz = self._tool_offset
        return (sx, sy, sz, oy * sz - oz * sy, oz * sx - ox * sz, ox * sy - oy * sx)

    def sample_at(self, t: float) -> ForceSample | None:
        """Take one sample at ``t``; deliver it unless the threshold withholds it."""
        raw = self.read_raw(t)
        self._seq += 1
        return self._deliver(self._seq, t, raw)

    def _run(self) -> None:
        period = 1.0 / self._pipeline.rate_hz
        now = self._now()
        # The last slot of the grid at ``phase`` before now (the loop adds a period).
        next_t = (math.floor(now / period - self.phase) + self.phase) * period
        while not self._stop.is_set():
            period = 1.0 / self._pipeline.rate_hz
            next_t += period
            delay = next_t - self._now()
            if delay > 0:
                time.sleep(delay)
            late = self._now() - next_t
            if late > MAX_CATCH_UP_S:
                # Far behind (the machine stalled): those slots' samples are lost; their
                # numbers are skipped, so the sequence shows it, as a real sensor's lost
                # packets do.
                missed = math.floor(late / period)
                self.overruns += missed
                self._seq += missed
                next_t += missed * period
            # Each sample at its own slot, the sensor's clock, as a real sensor times its
            # samples: woken late, the thread takes the slots it missed at once, but
            # their times keep the 1 kHz grid (stamped when taken, a stall left 66 ms
            # gaps and then bursts of samples µs apart in the stream and recordings).
            self.sample_at(next_t)
