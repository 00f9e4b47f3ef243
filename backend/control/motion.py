"""A command's geometry on one arm: from an increment, a joint step or an absolute
target to the joint target the driver is sent, within that arm's limits
(docs/architecture.md, "What cartesian_increment checks", steps 3 to 9).

Kept apart from the DecisionServer (decision.py) because these checks know one arm
(``ArmGuard``: its model, limits and force state) and nothing of who sends the
command: the client, the lease, the e-stop, a command's age and the driver's call are
the DecisionServer's, which calls these between its own checks. Pure and synchronous:
no await, so nothing can change between a check here and the next."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, WorkingFrame
from telerobot.drivers.robot.kinematics import check_rotation, check_vector
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.errors import LimitExceeded, SafetyStop
from telerobot.server.control.slave_port import SlavePort


def interval(last: float | None, now: float) -> float:
    """Time the speed limit allows for this increment: since the client's last command
    to this arm (``last``), within [1 ms, 100 ms] so a pause does not bank a big jump."""
    if last is None:
        return 0.1
    return min(max(now - last, 0.001), 0.1)


def scaled_increment(
    guard: ArmGuard, dX: FloatArray, rotvec: FloatArray, scale: float
) -> tuple[FloatArray, FloatArray, float, float]:
    """A Cartesian increment checked and scaled by the master-to-slave ``scale``, within
    the per-command step limit: (ΔX, rotation vector, |ΔX| m, angle rad)."""
    dX = check_vector("position increment", dX, 3) * scale
    rv = check_vector("rotation increment", rotvec, 3) * scale
    with np.errstate(over="ignore"):  # 1e300 is refused below, not a warning
        step, angle = float(np.linalg.norm(dX)), float(np.linalg.norm(rv))
    lim = guard.limits
    if step > lim.max_step_m or angle > lim.max_step_rad:
        raise LimitExceeded(
            f"increment of {step * 1000:.1f} mm / {math.degrees(angle):.1f}° (after scale "
            f"{scale:g}) exceeds the per-command limit of "
            f"{lim.max_step_m * 1000:.0f} mm / {math.degrees(lim.max_step_rad):.1f}°"
        )
    return dX, rv, step, angle


def cartesian_target(
    guard: ArmGuard,
    dX: FloatArray,
    rv: FloatArray,
    step: float,
    angle: float,
    *,
    frame: WorkingFrame,
    dt: float,
    now: float,
    port: SlavePort | None,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """A checked increment (``scaled_increment``) as a joint target from the arm's
    target joints: slowed to the speed limits over ``dt`` (to ``contact_speed_m_s``
    towards the last contact), kept to a master's energy (``port``), applied in
    ``frame``, the force stop's back-away rule and the workspace checked, then the
    differential IK. Returns (q, the joints it starts from, ΔX as moved, the share of
    the increment kept)."""
    lim = guard.limits
    seed = guard.robot.target_joints
    T0 = guard.kinematics.fk(seed).copy()
    speed = lim.max_speed_m_s
    if guard.approaches_last_contact(T0, dX, rv, frame, now):
        speed = min(speed, lim.contact_speed_m_s)
    factor = min(1.0, speed * dt / step if step else 1.0)
    factor = min(factor, lim.max_angular_speed_rad_s * dt / angle if angle else 1.0)
    dX, rv = dX * factor, rv * factor
    if port is not None:
        dX = port.allow(dX, T0[:3, 3])
    T = guard.kinematics.apply_increment(T0, dX, pin.exp3(rv), frame)
    if guard.force_limited and float((T[:3, 3] - T0[:3, 3]) @ guard.force_base) <= 0.0:
        raise SafetyStop(
            guard.said("force limit: only moves that back away from the contact are allowed")
        )
    guard.check_workspace(T[:3, 3])
    q = guard.kinematics.jog(T, seed)  # an increment: the differential solver
    return q, seed, dX, factor


def joint_step_target(
    guard: ArmGuard, dq: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray, float]:
    """A joint increment as a joint target from the arm's target joints: the
    per-command step limit, the force stop, slowed to the joint speed limit over
    ``dt``, the joints' range and the workspace. Returns (q, the joints it starts from,
    the share of the increment kept)."""
    dq = check_vector("joint increment", dq, guard.dof)
    lim = guard.limits
    biggest = float(np.max(np.abs(dq)))
    if biggest > lim.max_joint_step_rad:
        raise LimitExceeded(
            f"joint increment of {math.degrees(biggest):.1f}° exceeds the per-command limit of "
            f"{math.degrees(lim.max_joint_step_rad):.1f}°"
        )
    guard.check_not_force_limited()
    allowed = lim.max_joint_speed_rad_s * dt
    factor = min(1.0, allowed / biggest) if biggest > 0 else 1.0
    dq = dq * factor
    seed = guard.robot.target_joints
    q = seed + dq
    guard.kinematics.check_joint_limits(q)
    guard.check_workspace(guard.kinematics.fk(q)[:3, 3])
    return q, seed, factor


def joints_target(guard: ArmGuard, q: FloatArray, *, force_stop: bool = True) -> FloatArray:
    """An absolute joint target: the joints' range and the workspace; with
    ``force_stop``, refused while the arm's force stop holds (an initialisation is
    not)."""
    q = check_vector("joints", q, guard.dof)
    if force_stop:
        guard.check_not_force_limited()
    guard.kinematics.check_joint_limits(q)
    guard.check_workspace(guard.kinematics.fk(q)[:3, 3])
    return q


def pose_target(guard: ArmGuard, position: FloatArray, rotation: FloatArray) -> FloatArray:
    """An absolute pose (4×4) for the full IK, refused while the force stop holds or
    outside the workspace."""
    p = check_vector("position", position, 3)
    R = check_rotation("orientation", rotation)
    guard.check_not_force_limited()
    guard.check_workspace(p)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def check_joint_jump(guard: ArmGuard, q: FloatArray, seed: FloatArray) -> None:
    """The joint-step limit on what the IK made of an increment: a near-singular pose
    turns a joint a long way for a small move."""
    jump = [abs(a - b) for a, b in zip(q.tolist(), seed.tolist(), strict=True)]
    worst = max(range(len(jump)), key=jump.__getitem__)
    if jump[worst] > guard.limits.max_joint_step_rad:
        raise LimitExceeded(
            f"too close to a singularity: {guard.joint_label(worst)} would turn "
            f"{math.degrees(jump[worst]):.1f}° for this small move"
        )
