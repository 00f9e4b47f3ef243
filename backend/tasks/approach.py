"""The approach: how a task gets from where the arm is to its first pose when the
operator confirms it (``approach: true``), and the tool's way there for the page's
ghost of it (``POST /tasks/preview``'s ``approach``).

**In joints, not along the tool.** The move is the straight line in joint space from
the arm's commanded joints to the first pose's joints (the IK solution nearest them):
every joint turns in proportion, none more than its own share of the distance. The
approach used to be Cartesian: a straight tool line, each period's step solved by IK.
Near a wrist singularity a small tool rotation asks a large wrist turn, and after the
README's own script (joint 1 turned 0.1 rad, the tool 61 mm / 5.7° from a pose taught
before it) the first step was refused ("too close to a singularity: joint 4 would turn
14.8° for this small move") though joint 1 alone undoes it. A joint line has no such
point on the way, and is what undoing a joint move looks like.

Each period the task sends one *joint increment* along the line through the
DecisionServer (lease, e-stop, dead-man, per-command step, joint speed, joint limits,
workspace), no larger than the approach's joint speed and than its tool speed allow
(the tool's chord measured by FK), so the guarded move is slow at the tool too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, InvalidCommand, TelerobotError
from telerobot.drivers.robot.kinematics import ArmKinematics
from telerobot.server.control.errors import LimitExceeded
from telerobot.server.control.limits import SafetyLimits

# The tool's positions along the approach given for its ghost: one per degree of the
# joint that turns most, at most this many.
APPROACH_POINTS = 100


@dataclass(frozen=True)
class ApproachPlan:
    """The joint line from ``start`` to ``goal`` (the first pose's joints)."""

    start: FloatArray  # joints it leaves from (the commanded target when planned)
    goal: FloatArray  # joints at the task's first pose
    positions: FloatArray  # (k, 3) the tool along the way, base frame, m (start, …, goal)

    @property
    def span_rad(self) -> float:
        """How far the joint that turns most turns."""
        return float(np.max(np.abs(self.goal - self.start))) if len(self.goal) else 0.0


def plan_approach(
    kinematics: ArmKinematics,
    limits: SafetyLimits,
    q_from: FloatArray,
    position: FloatArray,
    rotation: FloatArray,
    *,
    tolerance_m: float,
    tolerance_rad: float,
) -> ApproachPlan:
    """The joint move from ``q_from`` to the tool pose (``position``, ``rotation``),
    checked before anything moves: the pose reachable within the joint limits (within
    ``tolerance_m`` / ``tolerance_rad``, what the task's start asks) and the tool inside
    the workspace all the way. Raises ``InvalidCommand`` saying why not."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, position
    where = np.round(np.asarray(position, dtype=float), 3).tolist()
    try:
        goal = kinematics.ik(T, q_from)
    except TelerobotError as exc:
        raise InvalidCommand(
            f"the task's first pose ({where} m) cannot be approached: {exc}"
        ) from None
    reached = kinematics.fk(goal)
    off_m = float(np.linalg.norm(reached[:3, 3] - position))
    off_rad = float(np.linalg.norm(pin.log3(reached[:3, :3].T @ rotation)))
    if off_m > tolerance_m or off_rad > tolerance_rad:
        raise InvalidCommand(
            f"the task's first pose ({where} m) cannot be approached: the nearest this arm "
            f"gets is {off_m * 1000:.1f} mm / {math.degrees(off_rad):.1f}° from it (a task "
            "recorded on another arm?)"
        )
    span = float(np.max(np.abs(goal - q_from))) if len(goal) else 0.0
    n = min(APPROACH_POINTS - 1, max(1, math.ceil(span / math.radians(1.0))))
    joints = q_from + np.linspace(0.0, 1.0, n + 1)[:, None] * (goal - q_from)
    positions = np.array([kinematics.fk(q)[:3, 3] for q in joints])
    for p in positions:
        if not limits.in_workspace(p):
            lo, hi = limits.workspace_min, limits.workspace_max
            box = ", ".join(f"{a} {lo[i]:.2f}…{hi[i]:.2f}" for i, a in enumerate("xyz"))
            raise LimitExceeded(
                f"the approach to the task's first pose would take the tool to "
                f"{np.round(p, 3).tolist()} m, outside the workspace ({box} m): move the "
                "arm nearer the first pose first"
            )
    return ApproachPlan(np.array(q_from, dtype=float), goal, positions)


def approach_step(
    kinematics: ArmKinematics,
    q: FloatArray,
    goal: FloatArray,
    dt: float,
    *,
    joint_speed_rad_s: float,
    tool_speed_m_s: float,
    max_step_rad: float,
) -> FloatArray:
    """One period's joint increment from ``q`` toward ``goal`` along the line between
    them: the rest of the way, or the share of it the joint speed, the tool's speed and
    the per-command step allow (all joints scaled alike, so it stays on the line)."""
    dq: FloatArray = np.asarray(goal - q, dtype=float)
    biggest = float(np.max(np.abs(dq))) if len(dq) else 0.0
    if biggest == 0.0:
        return dq
    share = min(1.0, joint_speed_rad_s * dt / biggest, max_step_rad / biggest)
    moved = float(np.linalg.norm(kinematics.fk(q + dq * share)[:3, 3] - kinematics.fk(q)[:3, 3]))
    allowed = tool_speed_m_s * dt
    if moved > allowed:
        share *= allowed / moved
    result: FloatArray = dq * share
    return result
