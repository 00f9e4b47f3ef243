"""Safety limits the DecisionServer enforces on every command, and how far the arm
goes before it is at rest once a stop is called (``stopping``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand, StopSpec
from telerobot.drivers.robot.motion import cartesian_stop, stop_time

# Tool speeds (m/s) GET /api/v1/safety states stopping figures for, besides the limit.
STOPPING_SPEEDS_M_S = (0.05, 0.1)


@dataclass(frozen=True)
class SafetyLimits:
    # Tool position must stay inside this box (base frame, metres).
    workspace_min: FloatArray = field(default_factory=lambda: np.array([-0.2, -0.8, 0.30]))
    workspace_max: FloatArray = field(default_factory=lambda: np.array([1.05, 0.8, 1.60]))
    max_step_m: float = 0.02  # largest translation one incremental command may ask for
    max_step_rad: float = 0.10  # largest rotation one incremental command may ask for
    max_joint_step_rad: float = 0.10  # largest joint change one incremental command may cause
    max_speed_m_s: float = 0.25  # translation speed of the commanded target
    max_angular_speed_rad_s: float = 1.0
    max_joint_speed_rad_s: float = 1.0  # for joint increments
    force_limit_n: float = 60.0  # contact force that stops motion
    force_release_ratio: float = 0.8  # the force stop clears below this share of the limit
    # A force above contact_force_n marks a contact: for contact_memory_s, moving back
    # toward it goes no faster than contact_speed_m_s. At full speed the arm strikes the
    # surface again before a force stop can act (a master arm bouncing off the simulated
    # block hit it at 7.5 cm/s: 469 N against the 60 N limit, 9.5 mm deep).
    contact_force_n: float = 15.0
    contact_speed_m_s: float = 0.02
    contact_memory_s: float = 2.0
    deadman_timeout_s: float = 0.15  # quiet controller → stop (checked every tick)
    tick_s: float = 0.02  # how often the dead-man is checked
    # A lease holder silent past the dead-man has its arm stopped at once but keeps the
    # lease this much longer: a busy machine's 200 ms stall costs a stop, not control.
    lease_grace_s: float = 2.0
    # A command from a client on the server's clock (HELLO's SYNCED_CLOCK) that is older
    # than this when it arrives is dropped, not executed late: on a slow or bursty link
    # a backlog must not replay the operator's past motions.
    max_command_age_s: float = 0.25

    def __post_init__(self) -> None:
        lo, hi = (
            np.asarray(self.workspace_min, dtype=float),
            np.asarray(self.workspace_max, dtype=float),
        )
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(lo < hi):
            raise InvalidCommand("workspace_min must be below workspace_max on every axis")
        for name in (
            "max_step_m",
            "max_step_rad",
            "max_joint_step_rad",
            "max_speed_m_s",
            "max_angular_speed_rad_s",
            "max_joint_speed_rad_s",
            "force_limit_n",
            "contact_force_n",
            "contact_speed_m_s",
            "max_command_age_s",
            "contact_memory_s",
            "deadman_timeout_s",
            "tick_s",
            "lease_grace_s",
        ):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise InvalidCommand(f"{name} must be a positive number, got {v!r}")
        if self.deadman_timeout_s + self.tick_s > 0.2:
            raise InvalidCommand(
                "deadman_timeout_s + tick_s must stay within 0.2 s (a silent client's arm "
                "starts stopping within 200 ms)"
            )

    def in_workspace(self, p: FloatArray, tol: float = 1e-9) -> bool:
        lo, hi = self.workspace_min.tolist(), self.workspace_max.tolist()  # floats: a hot path
        return all(a - tol <= x <= b + tol for x, a, b in zip(p.tolist(), lo, hi, strict=True))


@dataclass(frozen=True)
class Stopping:
    """Time and distance to rest from one tool speed, at one pose, worst direction."""

    speed_m_s: float
    time_s: float  # from the stop (lease lapse, e-stop, force limit) to the arm at rest
    distance_m: float  # the tool's travel in that time
    # From a controller's last message, when it goes silent: the dead-man's detection
    # time (the arm assumed to go on at full speed meanwhile), then the stop.
    after_silence_time_s: float
    after_silence_distance_m: float


def stopping(
    limits: SafetyLimits,
    spec: StopSpec,
    jacobian: FloatArray,
    speeds: tuple[float, ...] = STOPPING_SPEEDS_M_S,
) -> list[Stopping]:
    """Stopping time and distance for each of ``speeds`` below the speed limit and
    the limit itself, at the pose whose tool Jacobian is given: ``spec``'s reaction
    time at full speed, then a synchronised stop at the drives' limit
    (``cartesian_stop``)."""
    detect = limits.deadman_timeout_s + limits.tick_s
    table = []
    for v in sorted({*(v for v in speeds if v < limits.max_speed_m_s), limits.max_speed_m_s}):
        braking_s, braking_m = cartesian_stop(jacobian, v, spec.decel, spec.vmax)
        time_s = spec.reaction_s + braking_s
        distance_m = v * spec.reaction_s + braking_m
        table.append(Stopping(v, time_s, distance_m, detect + time_s, v * detect + distance_m))
    return table


def full_speed_stop_s(spec: StopSpec) -> float:
    """Time to rest from every joint at its speed limit (a scripted move at full speed)."""
    return spec.reaction_s + stop_time(spec.vmax, spec.decel)
