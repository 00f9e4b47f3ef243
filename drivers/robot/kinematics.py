"""What every arm's kinematic model shares, whichever arm it is: the checks every
command passes, the tool transform, increments in a working frame, the jog solver, and
the interface the server and the drivers read (``ArmKinematics``).

The PUMA 560 keeps its closed-form model (``telerobot.drivers.robot.puma560.kinematics``); any
other arm gets a numeric one from its URDF (``telerobot.drivers.robot.models.numeric``). Both
satisfy ``ArmKinematics``, so nothing above the drivers asks which arm it holds.

Two inverse kinematics: ``ik`` for an absolute pose (anywhere in the workspace, the
arm's full solver), ``jog`` for a small increment from the current joints (differential
IK, ``PinocchioKinematics.jog``: one or two Jacobian solves whatever the arm, issue 50).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import ClassVar, Final, Protocol

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, InvalidCommand, WorkingFrame


class ArmKinematics(Protocol):
    """An arm's kinematic model with its tool: what the server and the drivers use."""

    qlim: FloatArray  # (n, 2) lower, upper, radians

    @property
    def joint_names(self) -> tuple[str, ...]: ...
    @property
    def tool(self) -> FloatArray: ...
    @tool.setter
    def tool(self, T: FloatArray) -> None: ...
    def fk(self, q: FloatArray) -> FloatArray: ...
    def fk_flange(self, q: FloatArray) -> FloatArray: ...
    def link_origins(self, q: FloatArray) -> FloatArray:
        """Origins of the base, each joint and the tool ((n + 2) × 3), for drawing."""
        ...

    def jacobian(self, q: FloatArray) -> FloatArray: ...
    def apply_increment(
        self, T: FloatArray, dX: FloatArray, dM: FloatArray, frame: WorkingFrame
    ) -> FloatArray: ...
    def within_limits(self, q: FloatArray, tol: float = 1e-9) -> bool: ...
    def check_joint_limits(self, q: FloatArray) -> None: ...
    def ik(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """Joints reaching the tool pose ``T`` within the limits, nearest ``seed``."""
        ...

    def jog(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """Joints reaching ``T``, a small increment from ``seed`` (the current joints):
        what ``ik`` would answer, in a Jacobian solve or two. Refuses as ``ik`` does."""
        ...


def check_vector(name: str, v: object, size: int) -> FloatArray:
    """A finite float vector of the given size, or a clear ``InvalidCommand``."""
    # Fast path (every command passes here): a float64 vector whose sum is finite.
    if (
        isinstance(v, np.ndarray)
        and v.dtype == np.float64
        and v.shape == (size,)
        and math.isfinite(v.sum())
    ):
        return v.copy()  # callers may keep it: never alias theirs
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidCommand(f"{name} must be {size} numbers: {exc}") from None
    if arr.shape != (size,):
        raise InvalidCommand(f"{name} must have {size} values, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidCommand(f"{name} contains NaN or infinity: {arr.tolist()}")
    return arr


def check_rotation(name: str, R: object, tol: float = 1e-6) -> FloatArray:
    """A proper 3×3 rotation matrix (orthonormal, det +1), or a clear ``InvalidCommand``."""
    try:
        arr = np.asarray(R, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InvalidCommand(f"{name} must be a 3x3 matrix: {exc}") from None
    if arr.shape != (3, 3):
        raise InvalidCommand(f"{name} must be a 3x3 matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InvalidCommand(f"{name} contains NaN or infinity")
    if np.abs(arr.T @ arr - np.eye(3)).max() > tol or np.linalg.det(arr) < 0:
        raise InvalidCommand(f"{name} is not a rotation matrix (orthonormal with det +1)")
    return arr


def tool_transform(length: float) -> FloatArray:
    """A gripper of ``length`` metres along the flange's z axis."""
    T = np.eye(4)
    T[2, 3] = length
    return T


def apply_increment(
    T: FloatArray,
    dX: FloatArray,
    dM: FloatArray,
    frame: WorkingFrame,
    tool: FloatArray,
    tool_inv: FloatArray,
) -> FloatArray:
    """The tool pose reached from ``T`` by the increment (dX, dM) expressed in ``frame``:
    base (translate along / rotate about base axes, pivot at the tool point), tool
    (tool axes, pivot at the tool point) or wrist (flange axes, pivot at the wrist)."""
    delta = np.eye(4)
    delta[:3, :3], delta[:3, 3] = dM, dX
    if frame is WorkingFrame.BASE:
        out = T.copy()
        out[:3, :3] = dM @ T[:3, :3]
        out[:3, 3] = T[:3, 3] + dX
        return out
    if frame is WorkingFrame.TOOL:
        result: FloatArray = T @ delta
        return result
    if frame is WorkingFrame.WRIST:
        result = T @ tool_inv @ delta @ tool
        return result
    raise InvalidCommand(f"unknown working frame {frame!r}")


def _inv3_damped(M: FloatArray, damping2: float) -> FloatArray:
    """(M + λ² I)⁻¹ of a symmetric 3×3 ``M``, in closed form: a third of
    ``numpy.linalg.inv``'s time, which is mostly its overhead at this size."""
    (a, b, c), (_, e, f), (_, _, i) = M.tolist()
    a, e, i = a + damping2, e + damping2, i + damping2
    A, B, C = e * i - f * f, c * f - b * i, b * f - c * e
    s = 1.0 / (a * A + b * B + c * C)
    D, E, F = (a * i - c * c) * s, (b * c - a * f) * s, (a * e - b * b) * s
    A, B, C = A * s, B * s, C * s
    return np.array(((A, B, C), (B, D, E), (C, E, F)))


def joint_limit_faults(
    q: FloatArray, qlim: FloatArray, names: tuple[str, ...], tol: float = 1e-9
) -> list[str]:
    """Each joint of ``q`` past its limit, said for a person (empty: all within)."""
    return [
        f"{names[i]} = {math.degrees(q[i]):.2f}° "
        f"(limits {math.degrees(qlim[i, 0]):g}…{math.degrees(qlim[i, 1]):g}°)"
        for i in range(len(q))
        if not (qlim[i, 0] - tol <= q[i] <= qlim[i, 1] + tol)
    ]


# The jog solver (``PinocchioKinematics.jog``).
# Newton steps before an increment goes to the arm's own solver (``_jog_unmet``): a
# 0.2 mm increment is met in one, the largest one command may ask (20 mm) in three.
JOG_STEPS: Final = 4
# Damping λ of the position's least squares (m/rad): a regularisation, not a damping
# (it keeps the 3×3 inverse finite with fewer than three joints free). The position is
# met, near a singularity by a large joint motion, which the server's joint-step limit
# refuses, as it refuses ``ik``'s.
JOG_POSITION_DAMPING: Final = 1e-6
# The orientation comes second, solved in what the position leaves free, by damped
# least squares with λ = ε iterated once: a direction in which those joints turn the
# tool by σ rad/rad is followed to a share 1 − (ε²/(σ² + ε²))² of what it asks, all of
# it where σ ≫ ε (the PUMA's wrist away from its singularity, most SO-101 poses: a
# 0.5 rad/rad direction is short by 3e-6 of its share), next to nothing where σ ≪ ε.
# Near a pose where those joints barely turn the tool (an SO-101's lift, elbow and wrist
# flex about to line up), undamped least squares swings them by tenths of a radian for
# a hundredth of a milliradian; damped, the joints stay still and the orientation gives
# that up.
JOG_ORIENTATION_EPSILON: Final = 0.02
_POSITION_DAMPING2: Final = JOG_POSITION_DAMPING**2
_ORIENTATION_EPSILON2: Final = JOG_ORIENTATION_EPSILON**2


class PinocchioKinematics(ABC):
    """What a kinematic model held as a Pinocchio model with a tool frame does the same
    for every arm: the tool (checked, its inverse kept), FK of the tool and the flange,
    the joints' origins, the Jacobian, increments in a working frame, the limits, the
    jog solver. A subclass builds the model (``_build_model``: sets ``model``, ``_data``,
    ``_flange_id``, ``_tool_id`` for the current ``_tool``) and solves the IK.

    Not thread-safe (one Pinocchio ``Data`` per instance): give each thread its own."""

    qlim: FloatArray  # (n, 2)
    model: pin.Model
    _data: pin.Data
    _flange_id: int
    _tool_id: int
    # Tolerances a jog's result meets (a subclass's instances may set their own).
    position_tol_m: float = 1e-6
    orientation_tol_rad: float = 1e-5
    # Whether ``ik`` meets the whole pose or refuses it (the PUMA's closed form): then a
    # jog whose orientation the joints cannot hold goes to ``ik`` too. False: ``ik``
    # puts the position first and meets the orientation as nearly as the arm can (the
    # numeric IK), and so does the jog.
    exact_orientation: ClassVar[bool] = False
    # Of the last ``jog``: the Newton steps it took (0: the seed was the goal; none
    # when it went to the arm's solver) and its residual (metres, radians).
    last_jog_steps: int | None = None
    last_jog_residual: tuple[float, float] = (0.0, 0.0)

    @abstractmethod
    def _build_model(self) -> None: ...

    @abstractmethod
    def ik(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """Joints reaching the tool pose ``T`` within the limits, nearest ``seed``: the
        arm's full solver, for absolute moves (``jog`` for increments)."""

    @property
    def tool(self) -> FloatArray:
        return self._tool.copy()

    @tool.setter
    def tool(self, T: FloatArray) -> None:
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InvalidCommand("tool transform must be a finite 4x4 matrix")
        check_rotation("tool rotation", T[:3, :3])
        self._tool = T.copy()
        self._tool_inv: FloatArray = np.linalg.inv(T).astype(float)
        self._tool_is_identity = bool(np.allclose(T, np.eye(4), atol=0, rtol=0))
        self._build_model()
        self._prepare_jog()

    def fk(self, q: FloatArray) -> FloatArray:
        """Tool pose in the base frame as a 4×4 homogeneous matrix."""
        # Joint placements, then only the tool frame: half the cost of all frames.
        pin.forwardKinematics(self.model, self._data, q)
        result: FloatArray = pin.updateFramePlacement(
            self.model, self._data, self._tool_id
        ).homogeneous
        return result

    def fk_flange(self, q: FloatArray) -> FloatArray:
        pin.forwardKinematics(self.model, self._data, q)
        result: FloatArray = pin.updateFramePlacement(
            self.model, self._data, self._flange_id
        ).homogeneous
        return result

    def link_origins(self, q: FloatArray) -> FloatArray:
        """Origins of the base, each joint and the tool ((n + 2) × 3), for drawing."""
        pin.framesForwardKinematics(self.model, self._data, q)
        pts = [self._data.oMi[i].translation for i in range(1, self.model.njoints)]
        return np.array([np.zeros(3), *pts, self._data.oMf[self._tool_id].translation])

    def jacobian(self, q: FloatArray) -> FloatArray:
        """6×n geometric Jacobian of the tool point: rows vx vy vz wx wy wz, base frame."""
        J: FloatArray = pin.computeFrameJacobian(
            self.model, self._data, q, self._tool_id, pin.LOCAL_WORLD_ALIGNED
        )
        return J

    def apply_increment(
        self, T: FloatArray, dX: FloatArray, dM: FloatArray, frame: WorkingFrame
    ) -> FloatArray:
        """The tool pose reached from ``T`` by the increment (dX, dM) in ``frame``."""
        return apply_increment(T, dX, dM, frame, self._tool, self._tool_inv)

    def within_limits(self, q: FloatArray, tol: float = 1e-9) -> bool:
        return bool(np.all(q >= self.qlim[:, 0] - tol) and np.all(q <= self.qlim[:, 1] + tol))

    # ------------------------------------------------------------- jog
    def _prepare_jog(self) -> None:
        """What every jog reads: the joints that move the tool (an SO-101's gripper does
        not: its Jacobian columns are masked to zero), the limits."""
        model = self.model
        n = len(self.qlim)
        if model.nq != model.nv or model.nq != n:
            raise InvalidCommand("the jog solver needs one coordinate per joint")
        parent = model.frames[self._tool_id].parentJoint
        chain = {model.joints[j].idx_q for j in model.supports[parent] if j > 0}
        mask = np.array([float(i in chain) for i in range(n)])
        self._jog_mask: FloatArray | None = None if mask.all() else mask
        self._jog_lo = np.ascontiguousarray(self.qlim[:, 0], dtype=float)
        self._jog_hi = np.ascontiguousarray(self.qlim[:, 1], dtype=float)

    def jog(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """Joints within the limits reaching the tool pose ``T``, a small increment
        from ``seed`` (the current joints): differential inverse kinematics, for
        Cartesian jogging. Each Newton step is one prioritised least-squares solve on
        the tool's 6×n Jacobian (base-aligned axes at the tool point, as ``jacobian``),
        warm-started at ``seed``: the position first, then the orientation in the
        freedom the position leaves (its null space), in 3×3 algebra (``_jog_step``).
        A 0.2 mm increment is met in one step, and a step costs the same for five
        joints as for six.

        Joint limits: a joint the step would take past a limit is held at it and the
        step solved again without it, as ``ik`` keeps them.

        An arm with six joints (the PUMA 560) meets the position and the orientation.
        One with five (the SO-101) meets the position and cannot, from most poses,
        keep the orientation while the tool moves sideways: the orientation changes by
        the least rotation the move needs (the two joints the position leaves free
        turn the tool as near the asked orientation as they can; see
        ``JOG_ORIENTATION_EPSILON`` for where they barely can), and the next increment
        starts from the orientation that left. A long sideways jog turns the tool
        about the axis the wrist lacks; ``last_jog_residual`` says by how much this
        one missed.

        What the few steps cannot meet (a joint limit holding the position off, a
        singularity, the edge of the reach; and, where ``exact_orientation``, an
        orientation the joints cannot hold) goes to the arm's own solver
        (``_jog_unmet``), which answers or refuses as ``ik`` does: ``UnreachablePose``,
        ``JointLimitError``. A position short by more than ``position_tol_m`` is never
        returned."""
        lo, hi = self._jog_lo, self._jog_hi
        q: FloatArray = np.minimum(np.maximum(np.asarray(seed, dtype=float), lo), hi)
        p_goal, R_goal = T[:3, 3], T[:3, :3]
        tol_p, tol_o, exact = self.position_tol_m, self.orientation_tol_rad, self.exact_orientation
        J, e_p, e_o = self._jog_error(q, p_goal, R_goal)
        left = 0.0  # the orientation error the last step's free joints could not remove
        for step in range(JOG_STEPS + 1):
            pos, rot = math.sqrt(e_p @ e_p), math.sqrt(e_o @ e_o)
            if pos <= tol_p and (rot <= tol_o or (not exact and rot <= left + tol_o)):
                self.last_jog_steps, self.last_jog_residual = step, (pos, rot)
                return q
            if step == JOG_STEPS:
                break
            q, left = self._jog_step(J, e_p, e_o, q)
            J, e_p, e_o = self._jog_error(q, p_goal, R_goal)
        self.last_jog_steps = None
        return self._jog_unmet(T, seed, q)

    def _jog_error(
        self, q: FloatArray, p_goal: FloatArray, R_goal: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """At ``q``: the tool's Jacobian (base-aligned, at the tool point) and its
        position and orientation errors to the goal in the same axes (the rotation
        vector that takes the tool's orientation to the goal's, in the base frame)."""
        J: FloatArray = pin.computeFrameJacobian(
            self.model, self._data, q, self._tool_id, pin.LOCAL_WORLD_ALIGNED
        )
        M = self._data.oMf[self._tool_id]  # placed by computeFrameJacobian
        R = M.rotation
        e_p: FloatArray = p_goal - M.translation
        e_o: FloatArray = R @ pin.log3(R.T @ R_goal)
        return J, e_p, e_o

    def _jog_step(
        self, J: FloatArray, e_p: FloatArray, e_o: FloatArray, q: FloatArray
    ) -> tuple[FloatArray, float]:
        """One Newton step from ``q`` (n,): the joints it reaches and what it leaves of
        the orientation error (radians), in 3×3 algebra whatever n.

        With the Jacobian's Gram matrix J Jᵀ in blocks W = Jp Jpᵀ, C = Jo Jpᵀ, G = Jo Joᵀ,
        the prioritised step is dq = Jpᵀ a + Joᵀ z: z the orientation's least squares in
        the motions that leave the tool point where it is, (S + ε²) z = r with
        S = G − C W⁻¹ Cᵀ (A Aᵀ for A = Jo (I − Jp⁺ Jp): the Schur complement) and
        r = e_o − C W⁻¹ e_p (what the position's own step leaves of the orientation
        error), solved twice (iterated Tikhonov); a = W⁻¹ (e_p − Cᵀ z), which meets the
        position whatever z is (Jp dq = W a + Cᵀ z = e_p). Six joints: S is invertible
        and the orientation met; five: S has rank 2 and the orientation is met as near
        as the two free joints allow, the rotation neither makes left (its z moves no
        joint: Joᵀ z − Jpᵀ W⁻¹ Cᵀ z = Aᵀ z = 0). The orientation left, r − S z, is
        ε² × the second solve's change. A joint the step takes past a limit is held at
        it (its column zeroed, its share taken off both errors) and the step solved
        again with the others."""
        lo, hi = self._jog_lo, self._jog_hi
        # Joints off the tool's chain never move (their columns zeroed: a copy of J).
        mask = self._jog_mask
        copied = mask is not None
        if mask is not None:
            J = J * mask
        for _ in range(q.shape[0] + 1):  # each pass holds one joint more, at least
            K = J @ J.T
            C = K[3:, :3]
            Wi = _inv3_damped(K[:3, :3], _POSITION_DAMPING2)
            CWi = C @ Wi
            r = e_o - CWi @ e_p
            Si = _inv3_damped(K[3:, 3:] - CWi @ C.T, _ORIENTATION_EPSILON2)
            z = Si @ r
            dz = _ORIENTATION_EPSILON2 * (Si @ z)
            z += dz
            a = Wi @ (e_p - C.T @ z)
            q_next: FloatArray = q + J.T @ np.concatenate((a, z))
            out = (q_next < lo) | (q_next > hi)
            if not out.any():
                return q_next, _ORIENTATION_EPSILON2 * math.sqrt(dz @ dz)
            held = np.where(out, np.minimum(np.maximum(q_next, lo), hi), q)
            e_p = e_p - J[:3] @ (held - q)
            e_o = e_o - J[3:] @ (held - q)
            if not copied:
                J, copied = J.copy(), True
            J[:, out] = 0.0
            q = held  # exactly at the limits: the next pass leaves them there
        return np.minimum(np.maximum(q_next, lo), hi), _ORIENTATION_EPSILON2 * math.sqrt(dz @ dz)

    def _jog_unmet(self, T: FloatArray, seed: FloatArray, q: FloatArray) -> FloatArray:
        """An increment the jog's steps did not meet (``q``: where they ended): the
        arm's own solver answers, or refuses. By default ``ik`` (the PUMA's closed form:
        a few microseconds)."""
        return self.ik(T, seed)
