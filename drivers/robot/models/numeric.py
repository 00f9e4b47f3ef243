"""Kinematics of any arm from its URDF, through Pinocchio: FK, Jacobian and a numeric
inverse kinematics for arms without a closed form.

The IK is damped least squares with two priorities, warm-started from the current
joints. The tool's *position* comes first; its *orientation* is met with what the
arm has left (the null space of the position task). An arm with six joints in the
tool's chain reaches both exactly. One with five (the SO-101) reaches any position in
its workspace with the orientation as near as it can be, and says how near: a
Cartesian jog that also asks a rotation the arm cannot make still moves the tool where
it was sent. The damping grows with the error (λ² = k·|e|², Sugihara 2011), so
steps far from the goal stay small and the last steps converge like Gauss-Newton.
Joint limits are kept by clamping each step.

The result carries its residual (``last_residual``); a pose whose position cannot be
met within ``position_tol_m`` is refused as unreachable, nothing moved.

That is the solver for absolute poses. A jog (a small increment from the current
joints) is solved by the differential IK every arm shares
(``PinocchioKinematics.jog``: one or two Jacobian solves, position first and the
orientation in what it leaves); what its few steps cannot meet comes back here, to the
position alone from the current joints (``_jog_unmet``), refused as ``ik`` refuses.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final, TypedDict

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, InvalidCommand, JointLimitError, UnreachablePose
from telerobot.drivers.robot.kinematics import PinocchioKinematics, joint_limit_faults

MAX_ITERATIONS: Final = 60
# Position-only solves tried when the position is still short (the best so far, then
# the first restarts): each is bounded, as an unreachable pose must be refused quickly.
FALLBACK_STARTS: Final = 2
# Converged when a step moves the joints less than this (radians, largest joint).
STEP_TOL: Final = 1e-10
# Given up as stalled when the error is above this share of what it was
# STALL_WINDOW steps before (Gauss-Newton shrinks it far faster near a solution).
STALL_RATIO: Final = 0.95
STALL_WINDOW: Final = 4
_I3: Final = np.eye(3)


class UrdfKinematics(PinocchioKinematics):
    """FK, Jacobian and numeric IK of the chain from the URDF's root to ``flange`` plus
    the tool. Not thread-safe (one Pinocchio ``Data`` per instance)."""

    def __init__(
        self,
        urdf: str,
        flange: str,
        joint_names: Sequence[str],
        tool: FloatArray | None = None,
        *,
        position_tol_m: float = 1e-6,
        orientation_tol_rad: float = 1e-5,
        damping: float = 1e-3,
        restarts: int = 6,
    ) -> None:
        self._model_base = pin.buildModelFromXML(urdf)
        names = tuple(self._model_base.names[1:])
        if names != tuple(joint_names):
            raise InvalidCommand(f"the URDF's joints {names} are not the model's {joint_names}")
        if not self._model_base.existFrame(flange):
            raise InvalidCommand(f"the URDF has no link {flange!r} to mount a tool on")
        self._flange_name = flange
        self._names = names
        lo = np.asarray(self._model_base.lowerPositionLimit, float)
        hi = np.asarray(self._model_base.upperPositionLimit, float)
        self.qlim = np.stack([lo, hi], axis=1)
        self.qlim.setflags(write=False)
        self._lo, self._hi = lo, hi
        self.position_tol_m = position_tol_m
        self.orientation_tol_rad = orientation_tol_rad
        self._k = damping
        self.last_residual = (0.0, 0.0)  # metres, radians, of the last ik()
        rng = np.random.default_rng(0)
        middle = (lo + hi) / 2
        self._restarts = [middle, *(rng.uniform(lo, hi) for _ in range(restarts - 1))]
        self.last_iterations = 0
        self.tool = np.eye(4) if tool is None else tool

    # ------------------------------------------------------------- model
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._names

    def _build_model(self) -> None:
        model = self._model_base.copy()
        flange = model.frames[model.getFrameId(self._flange_name)]
        self._flange_id = model.getFrameId(self._flange_name)
        tool = pin.Frame(
            "tool",
            flange.parentJoint,
            self._flange_id,
            flange.placement * pin.SE3(self._tool),
            pin.FrameType.OP_FRAME,
        )
        self._tool_id = model.addFrame(tool)
        self.model = model
        self._data = model.createData()
        # How far the tool can be from the first joint: the sum of the links between
        # the joints that move it (a bound, so a pose past it is refused at once).
        chain = [j for j in model.supports[flange.parentJoint] if j > 0]
        self._carries_tool = np.array([j in chain for j in range(1, model.njoints)])
        offsets = [model.jointPlacements[j].translation for j in chain[1:]]
        last = model.frames[self._tool_id].placement.translation
        self._shoulder = model.jointPlacements[chain[0]].translation.copy()
        self._reach = float(sum(np.linalg.norm(o) for o in [*offsets, last]))

    # ------------------------------------------------------------- limits
    def check_joint_limits(self, q: FloatArray) -> None:
        bad = joint_limit_faults(q, self.qlim, self._names)
        if bad:
            raise JointLimitError("target is past a joint limit: " + "; ".join(bad))

    # ------------------------------------------------------------- inverse
    def ik(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """Joints within the limits reaching the tool pose ``T``, found from ``seed``
        (the current joints). The orientation is met as nearly as the arm can
        (``last_residual``); ``UnreachablePose`` if the position cannot be."""
        target = pin.SE3(T[:3, :3], T[:3, 3])
        self._check_reach(T)
        q = np.minimum(np.maximum(np.asarray(seed, dtype=float), self._lo), self._hi)
        q, it = self._solve(target, q)
        # A far move can end in a local minimum against a limit: start again from a
        # few fixed places across the joint space (only then: a warm start is quick).
        q, it = self._retry(target, q, it, self._restarts, self._solve)
        if self.last_residual[0] > self.position_tol_m:
            # Still short: the orientation task, kept in what the position leaves free,
            # can hold the position off against a joint limit (an SO-101 sent back to
            # its start position with an orientation it cannot have there stopped
            # 0.01–78 mm away). The position alone, limits as constraints, from the
            # best so far and then from a restart; the orientation is what it gets.
            starts = [q, *self._restarts][:FALLBACK_STARTS]
            q, it = self._retry(target, q, it, starts, self._position_only)
        self.last_iterations = it
        self._check_met(T)
        return q

    def _check_reach(self, T: FloatArray) -> None:
        """``UnreachablePose`` at once for a pose farther than the arm stretched out."""
        d = T[:3, 3] - self._shoulder
        far = math.sqrt(d @ d) - self._reach
        if far > self.position_tol_m:  # farther than the arm stretched out: no search
            self.last_residual, self.last_iterations = (far, math.inf), 0
            p = np.round(T[:3, 3], 4).tolist()
            raise UnreachablePose(
                f"the pose at {p} m is out of the {self._model_base.name}'s reach: "
                f"{far * 1000:.0f} mm farther than the arm stretched out"
            )

    def _check_met(self, T: FloatArray) -> None:
        """``UnreachablePose`` when the last solve left the position short."""
        pos_err = self.last_residual[0]
        if pos_err > self.position_tol_m:
            p = np.round(T[:3, 3], 4).tolist()
            raise UnreachablePose(
                f"the pose at {p} m is out of the {self._model_base.name}'s reach within "
                f"its joint limits: the nearest it gets is {pos_err * 1000:.2f} mm away"
            )

    def _jog_unmet(self, T: FloatArray, seed: FloatArray, q: FloatArray) -> FloatArray:
        """An increment the jog's steps did not meet: the position alone from the
        current joints (a joint at a limit held there, bounded like ``ik``'s fallback),
        the orientation what it gets; ``UnreachablePose`` as ``ik`` says it if the
        position is still short. No restarts: what they find is another configuration
        of the arm, a jump no increment may make (the joint-step limit refuses it)."""
        self._check_reach(T)
        target = pin.SE3(T[:3, :3], T[:3, 3])
        start = np.minimum(np.maximum(np.asarray(seed, dtype=float), self._lo), self._hi)
        q, self.last_iterations = self._position_only(target, start)
        self._check_met(T)
        return q

    def _retry(
        self,
        target: pin.SE3,
        q: FloatArray,
        it: int,
        starts: list[FloatArray],
        solve: Callable[[pin.SE3, FloatArray], tuple[FloatArray, int]],
    ) -> tuple[FloatArray, int]:
        """``solve`` from each of ``starts`` until the position is met, keeping the best
        (and its residual); the iterations counted on from ``it``."""
        for start in starts:
            if self.last_residual[0] <= self.position_tol_m:
                break
            best_q, best = q, self.last_residual
            # Joints that do not carry the tool (a gripper) keep the seed's value.
            q, more = solve(target, np.where(self._carries_tool, start, q))
            it += more
            if self.last_residual[0] > best[0]:
                q, self.last_residual = best_q, best
        return q, it

    def _solve(self, target: pin.SE3, q: FloatArray) -> tuple[FloatArray, int]:
        q, it = self._newton(target, q)
        if self.last_residual[0] > self.position_tol_m or (
            self.last_residual[1] > self.orientation_tol_rad and it == MAX_ITERATIONS
        ):
            # Not both met: the orientation is out of the arm's reach (or a limit is in
            # the way). Put the position first, the orientation in what it leaves.
            q, more = self._prioritised(target, q)
            it += more
        return q, it

    def _residual(self, target: pin.SE3, q: FloatArray) -> tuple[FloatArray, float, float]:
        """The tool's error to ``target`` in the tool frame (6,), and its position and
        orientation norms; leaves the joint Jacobians computed at ``q``."""
        pin.computeJointJacobians(self.model, self._data, q)
        error = pin.updateFramePlacement(self.model, self._data, self._tool_id).actInv(target)
        e: FloatArray = pin.log6(error).vector
        # log6's linear part is not the position error (the translation is, rotated).
        d = error.translation
        pos_err, rot_err = math.sqrt(d @ d), math.sqrt(e[3:] @ e[3:])
        self.last_residual = (pos_err, rot_err)
        return e, pos_err, rot_err

    def _newton(self, target: pin.SE3, q: FloatArray) -> tuple[FloatArray, int]:
        """Damped Gauss-Newton on the full 6-D error: few steps when the pose is
        reachable (the usual warm start). Stops when met or when it stalls."""
        lo, hi, model, data, tool = self._lo, self._hi, self.model, self._data, self._tool_id
        pos_tol, rot_tol, k = self.position_tol_m, self.orientation_tol_rad, self._k
        history = [math.inf] * STALL_WINDOW
        for it in range(MAX_ITERATIONS):
            e, pos_err, rot_err = self._residual(target, q)
            if pos_err <= pos_tol and rot_err <= rot_tol:
                return q, it
            size = float(e @ e)
            if size > STALL_RATIO * history[it % STALL_WINDOW]:
                return q, it  # barely better than a few steps ago: a minimum elsewhere
            history[it % STALL_WINDOW] = size
            J = pin.getFrameJacobian(model, data, tool, pin.LOCAL)
            A = J @ J.T
            A.flat[::7] += k * (e @ e) + 1e-12  # the damping, on the diagonal
            dq = J.T @ np.linalg.solve(A, e)
            if dq @ dq < STEP_TOL * STEP_TOL:
                return q, it  # a least-squares minimum that is not the pose
            q = np.minimum(np.maximum(q + dq, lo), hi)
        self._residual(target, q)
        return q, MAX_ITERATIONS

    def _prioritised(self, target: pin.SE3, q: FloatArray) -> tuple[FloatArray, int]:
        """The position exactly where it can be; the orientation as near as the joints
        the position leaves free allow (in the world-aligned frame at the tool)."""
        model, data, tool = self.model, self._data, self._tool_id
        history = [math.inf] * STALL_WINDOW
        for it in range(1, MAX_ITERATIONS + 1):
            pin.computeJointJacobians(model, data, q)
            M = pin.updateFramePlacement(model, data, tool)
            e_p = target.translation - M.translation
            e_o = M.rotation @ pin.log3(M.rotation.T @ target.rotation)
            self.last_residual = (math.sqrt(e_p @ e_p), math.sqrt(e_o @ e_o))
            size = self.last_residual[0] + 0.01 * self.last_residual[1]
            if size > STALL_RATIO * history[it % STALL_WINDOW]:
                break
            history[it % STALL_WINDOW] = size
            J = pin.getFrameJacobian(model, data, tool, pin.LOCAL_WORLD_ALIGNED)
            Jp, Jo = J[:3], J[3:]
            Jp_pinv = Jp.T @ np.linalg.inv(Jp @ Jp.T + (self._k * (e_p @ e_p) + 1e-12) * _I3)
            dq = Jp_pinv @ e_p
            Jo_n = Jo - (Jo @ Jp_pinv) @ Jp
            r = e_o - Jo @ dq
            dq = dq + Jo_n.T @ np.linalg.solve(Jo_n @ Jo_n.T + (self._k * (r @ r) + 1e-12) * _I3, r)
            q_next = np.minimum(np.maximum(q + dq, self._lo), self._hi)
            step = q_next - q
            q = q_next
            if step @ step < STEP_TOL * STEP_TOL:
                break
        self._residual(target, q)
        return q, it

    def _position_only(self, target: pin.SE3, q: FloatArray) -> tuple[FloatArray, int]:
        """Damped least squares on the tool's position alone. A joint at a limit that
        the step would push past is held there and the step solved again without it
        (clamping the step instead stalls: the other joints never make up for it)."""
        model, data, tool = self.model, self._data, self._tool_id
        lo, hi = self._lo, self._hi
        history = [math.inf] * STALL_WINDOW
        it = 0
        for it in range(1, MAX_ITERATIONS + 1):
            pin.computeJointJacobians(model, data, q)
            M = pin.updateFramePlacement(model, data, tool)
            e_p = target.translation - M.translation
            err = math.sqrt(e_p @ e_p)
            if err <= self.position_tol_m:
                break
            if err > STALL_RATIO * history[it % STALL_WINDOW]:
                break
            history[it % STALL_WINDOW] = err
            Jp = pin.getFrameJacobian(model, data, tool, pin.LOCAL_WORLD_ALIGNED)[:3]
            free = self._carries_tool.copy()
            dq = np.zeros_like(q)
            for _ in range(len(q)):
                J = Jp[:, free]
                damping = (self._k * (e_p @ e_p) + 1e-12) * _I3
                dq = np.zeros_like(q)
                dq[free] = J.T @ np.linalg.solve(J @ J.T + damping, e_p)
                blocked = free & (((q >= hi) & (dq > 0)) | ((q <= lo) & (dq < 0)))
                if not blocked.any():
                    break
                free &= ~blocked
            q_next = np.minimum(np.maximum(q + dq, lo), hi)
            if (q_next - q) @ (q_next - q) < STEP_TOL * STEP_TOL:
                break
            q = q_next
        self._residual(target, q)
        return q, it


_AXES: Final = {"RX": (1.0, 0.0, 0.0), "RY": (0.0, 1.0, 0.0), "RZ": (0.0, 0.0, 1.0)}


class ChainJoint(TypedDict):
    name: str
    parent: int  # index into the joints; -1: the base
    origin: list[list[float]]  # 4×4 in the parent joint's frame
    axis: list[float]


class ChainFlange(TypedDict):
    parent: int
    origin: list[list[float]]


class Chain(TypedDict):
    joints: list[ChainJoint]
    flange: ChainFlange


def describe_chain(urdf: str, flange: str) -> Chain:
    """The URDF's kinematic tree as plain numbers, for a client that computes forward
    kinematics itself (the page): each revolute joint's parent (an index into the list,
    -1 for the base), its placement in the parent joint's frame (4×4, row-major) and
    axis, and where the flange sits on its joint."""
    model = pin.buildModelFromXML(urdf)
    joints: list[ChainJoint] = []
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname().removeprefix("JointModel")
        if kind == "RevoluteUnaligned":
            axis = [float(x) for x in model.joints[j].extract().axis]
        elif kind in _AXES:
            axis = list(_AXES[kind])
        else:
            raise InvalidCommand(f"joint {model.names[j]!r} is {kind}: only revolute joints")
        joints.append(
            {
                "name": model.names[j],
                "parent": model.parents[j] - 1,
                "origin": np.round(model.jointPlacements[j].homogeneous, 12).tolist(),
                "axis": axis,
            }
        )
    frame = model.frames[model.getFrameId(flange)]
    return {
        "joints": joints,
        "flange": {
            "parent": frame.parentJoint - 1,
            "origin": np.round(frame.placement.homogeneous, 12).tolist(),
        },
    }
