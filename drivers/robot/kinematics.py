"""What every arm's kinematic model shares, whichever arm it is: the checks every
command passes, the tool transform, increments in a working frame, and the interface
the server and the drivers read (``ArmKinematics``).

The PUMA 560 keeps its closed-form model (``telerobot.drivers.robot.puma560.kinematics``); any
other arm gets a numeric one from its URDF (``telerobot.drivers.robot.models.numeric``). Both
satisfy ``ArmKinematics``, so nothing above the drivers asks which arm it holds.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Protocol

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


class PinocchioKinematics(ABC):
    """What a kinematic model held as a Pinocchio model with a tool frame does the same
    for every arm: the tool (checked, its inverse kept), FK of the tool and the flange,
    the joints' origins, the Jacobian, increments in a working frame, the limits. A
    subclass builds the model (``_build_model``: sets ``model``, ``_data``,
    ``_flange_id``, ``_tool_id`` for the current ``_tool``) and solves the IK.

    Not thread-safe (one Pinocchio ``Data`` per instance): give each thread its own."""

    qlim: FloatArray  # (n, 2)
    model: pin.Model
    _data: pin.Data
    _flange_id: int
    _tool_id: int

    @abstractmethod
    def _build_model(self) -> None: ...

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
