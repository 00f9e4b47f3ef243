"""PUMA 560 kinematics: forward kinematics and Jacobian through Pinocchio, and the
closed-form inverse kinematics with all eight configurations.

Standard DH parameters and joint limits as in Robotics Toolbox for Python's
``Puma560``. Joint i's transform is Rz(q_i) Tz(d_i) Tx(a_i) Rx(alpha_i). The
wrist centre is the origin of frames 4, 5 and 6 (a4 = a5 = d5 = d6 = 0).

Inverse kinematics (derived for this DH table; see docs/kinematics.md):

* wrist centre p = flange position. In the arm's vertical plane, with
  rho = a2 c2 + a3 c23 - d4 s23 and z = p_z - d1,
  p_x = rho c1 + d3 s1 and p_y = rho s1 - d3 c1, so rho = ±sqrt(p_x² + p_y² - d3²)
  (the two shoulder configurations) and q1 = atan2(p_y, p_x) - atan2(-d3, rho).
* a3 c3 - d4 s3 = (rho² + z² - a2² - a3² - d4²) / (2 a2) = L cos(q3 + phi), with
  L = hypot(a3, d4), phi = atan2(d4, a3): two elbow configurations.
* q2 = atan2(z, rho) - atan2(a3 s3 + d4 c3, a2 + a3 c3 - d4 s3).
* R_03 = Rz(q1) Ry(-q23) and R_36 = Rz(q4) Ry(-q5) Rz(q6): a ZYZ decomposition of
  R_03ᵀ R gives the wrist and its flipped twin (q4 + pi, -q5, q6 + pi).

At the wrist singularity (sin q5 ≈ 0) only q4 + q6 is defined: q4 keeps the
seed's value (the current joints) and q6 takes the rest, so the wrist never spins.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Final, Literal

import numpy as np
import pinocchio as pin

from telerobot.drivers.base import FloatArray, JointLimitError, UnreachablePose
from telerobot.drivers.robot.kinematics import (  # re-exported: the PUMA's users import them here
    PinocchioKinematics,
    check_rotation,
    check_vector,
    tool_transform,
)
from telerobot.drivers.robot.puma560.geometry import (  # DH … QLIM re-exported as well
    A2,
    A3,
    D1,
    D3,
    D4,
    DH,
    NAMED_POSES,
    PI,
    QLIM,
    QLIM_DEG,
    TWO_PI,
)

__all__ = [
    "DH",
    "NAMED_POSES",
    "QLIM",
    "QLIM_DEG",
    "Puma560Kinematics",
    "check_rotation",
    "check_vector",
    "tool_transform",
]

# Below this |sin q5| the wrist is treated as singular (q4 and q6 share one rotation).
WRIST_SINGULAR_SIN: Final = 1e-9
_L: Final = math.hypot(A3, D4)
_PHI: Final = math.atan2(D4, A3)
_TWO_A2: Final = 2.0 * A2
_K0: Final = A2 * A2 + A3 * A3 + D4 * D4


@dataclass(frozen=True)
class Configuration:
    arm: Literal["right", "left"]  # wrist centre in front of (right) or behind (left) the shoulder
    elbow: Literal["up", "down"]  # elbow above or below the shoulder-to-wrist line
    wrist: Literal["noflip", "flip"]  # q5 >= 0 or q5 < 0


@dataclass(frozen=True)
class IKSolutions:
    """All eight closed-form solutions of one pose.

    ``q[i]`` has angles wrapped to [-pi, pi); ``reachable[i]`` is False where the
    geometry has no solution (those rows are NaN). Index bits: 4 = shoulder
    (rho < 0), 2 = elbow branch, 1 = wrist flip.
    """

    q: FloatArray  # (8, 6)
    reachable: np.ndarray  # (8,) bool


def _wrap(a: float) -> float:
    return (a + PI) % TWO_PI - PI


def _branch(q: list[float]) -> tuple[float, float, bool]:
    """Which `_solve` branch ``q`` is on: shoulder sign of rho, elbow sign, wrist flipped."""
    rho = _rho(q[1], q[2])
    elbow = _wrap(q[2] + _PHI)
    return (1.0 if rho >= 0 else -1.0), (1.0 if elbow >= 0 else -1.0), q[4] < 0


def _rho(q2: float, q3: float) -> float:
    """Horizontal reach of the wrist centre in the arm's plane (negative: behind)."""
    return A2 * math.cos(q2) + A3 * math.cos(q2 + q3) - D4 * math.sin(q2 + q3)


class Puma560Kinematics(PinocchioKinematics):
    """FK and Jacobian from a Pinocchio model built from the DH table; closed-form IK.

    Not thread-safe (one Pinocchio ``Data`` per instance): give each thread its own.
    """

    joint_names: Final = tuple(f"joint{i}" for i in range(1, 7))
    # The closed form meets the whole pose or refuses it; so does a jog (an orientation
    # the joints cannot hold, at the wrist singularity, goes to ``ik``).
    exact_orientation: ClassVar[bool] = True

    def __init__(self, tool: FloatArray | None = None) -> None:
        self.qlim = QLIM.copy()
        self.qlim.setflags(write=False)  # the IK's fast path caches these limits as floats
        self._lo = [float(x) for x in QLIM[:, 0]]
        self._hi = [float(x) for x in QLIM[:, 1]]
        self.tool = np.eye(4) if tool is None else tool

    # ------------------------------------------------------------- model
    def _build_model(self) -> None:
        model = pin.Model()
        model.name = "puma560"
        parent = 0
        placement = pin.SE3.Identity()
        for i, (d, a, alpha) in enumerate(DH):
            jid = model.addJoint(
                parent,
                pin.JointModelRZ(),
                placement,
                f"joint{i + 1}",
                np.zeros(1),
                np.zeros(1),
                np.array([self.qlim[i, 0]]),
                np.array([self.qlim[i, 1]]),
            )
            # Inertias are placeholders: only kinematics is used here.
            model.appendBodyToJoint(jid, pin.Inertia.FromSphere(1.0, 0.05), pin.SE3.Identity())
            parent = jid
            placement = pin.SE3(pin.utils.rotate("x", alpha), np.array([a, 0.0, d]))
        # `placement` is now the link-6 DH transform (identity for the PUMA's d6 = a6 = 0).
        flange = pin.Frame("flange", parent, 0, placement, pin.FrameType.OP_FRAME)
        self._flange_id = model.addFrame(flange)
        tool = pin.Frame("tool", parent, 0, placement * pin.SE3(self._tool), pin.FrameType.OP_FRAME)
        self._tool_id = model.addFrame(tool)
        self.model = model
        self._data = model.createData()

    # ------------------------------------------------------------- forward
    def wrist_centre(self, q: FloatArray) -> FloatArray:
        pin.forwardKinematics(self.model, self._data, q)
        result: FloatArray = self._data.oMi[6].translation
        return result

    # ------------------------------------------------------------- limits
    def fit_limits(self, q: FloatArray, seed: FloatArray | None = None) -> FloatArray | None:
        """``q`` with each angle moved by whole turns into its limits, nearest ``seed``
        (or nearest zero); None if some joint cannot be placed inside its limits."""
        ref = [0.0] * 6 if seed is None else [float(x) for x in seed]
        fitted = self._fit_row([float(x) for x in q], ref)
        return None if fitted is None else np.array(fitted[0])

    def _fit_row(self, row: list[float], seed: list[float]) -> tuple[list[float], float] | None:
        """Pure-Python on purpose: for six angles it is twice as fast as numpy.
        Angles come within ±pi of [-pi, pi), so one whole turn either way suffices
        for limits within ±3pi. Returns the fitted row and its squared distance."""
        out: list[float] = []
        cost = 0.0
        for a, lo, hi, ref in zip(row, self._lo, self._hi, seed, strict=True):
            best = math.nan
            best_d = math.inf
            for x in (a - TWO_PI, a, a + TWO_PI):
                if lo - 1e-9 <= x <= hi + 1e-9 and abs(x - ref) < best_d:
                    best, best_d = x, abs(x - ref)
            if best_d == math.inf:
                return None
            out.append(min(max(best, lo), hi))
            cost += best_d * best_d
        return out, cost

    def check_joint_limits(self, q: FloatArray) -> None:
        if all(
            lo - 1e-9 <= a <= hi + 1e-9
            for a, lo, hi in zip(q.tolist(), self._lo, self._hi, strict=True)
        ):
            return
        bad = [
            f"joint {i + 1} = {math.degrees(q[i]):.2f}° (limits {lo:g}…{hi:g}°)"
            for i, (lo, hi) in enumerate(QLIM_DEG)
            if not (self.qlim[i, 0] - 1e-9 <= q[i] <= self.qlim[i, 1] + 1e-9)
        ]
        if bad:
            raise JointLimitError("target is past a joint limit: " + "; ".join(bad))

    # ------------------------------------------------------------- inverse
    def ik_all(self, T: FloatArray, seed: FloatArray | None = None) -> IKSolutions:
        """All eight closed-form solutions for the tool pose ``T`` (4×4).

        ``seed`` only matters at the wrist singularity, where q4 keeps its value.
        """
        rows, reach = self._solve(T, seed)
        return IKSolutions(q=np.array(rows), reachable=np.array(reach))

    def _solve(
        self,
        T: FloatArray,
        seed: FloatArray | None,
        rho_signs: tuple[float, ...] = (1.0, -1.0),
        elbow_signs: tuple[float, ...] = (1.0, -1.0),
    ) -> tuple[list[list[float]], list[bool]]:
        """Rows for the chosen shoulder and elbow branches, each with its two wrists."""
        if not self._tool_is_identity:
            T = T @ self._tool_inv
        (r00, r01, r02, px), (r10, r11, r12, py), (r20, r21, r22, pz) = T[:3].tolist()
        q4_seed = 0.0 if seed is None else float(seed[3])
        nan6 = [math.nan] * 6
        rows: list[list[float]] = []
        reach: list[bool] = []
        rr = px * px + py * py - D3 * D3
        z = pz - D1
        base = math.atan2(py, px)
        per_shoulder = 2 * len(elbow_signs)
        for rho_sign in rho_signs:
            if rr < 0.0:  # wrist centre inside the cylinder of radius d3: nothing reaches it
                rows += [nan6] * per_shoulder
                reach += [False] * per_shoulder
                continue
            rho = rho_sign * math.sqrt(rr)
            q1 = _wrap(base - math.atan2(-D3, rho))
            c1, s1 = math.cos(q1), math.sin(q1)
            # R' = Rz(-q1) R
            a00, a01, a02 = c1 * r00 + s1 * r10, c1 * r01 + s1 * r11, c1 * r02 + s1 * r12
            a10, a12 = c1 * r10 - s1 * r00, c1 * r12 - s1 * r02
            kk = (rho * rho + z * z - _K0) / (_TWO_A2 * _L)
            if kk > 1.0 + 1e-12 or kk < -1.0 - 1e-12:  # out of the arm's reach
                rows += [nan6] * per_shoulder
                reach += [False] * per_shoulder
                continue
            acos_k = math.acos(min(1.0, max(-1.0, kk)))
            for elbow_sign in elbow_signs:
                q3 = _wrap(elbow_sign * acos_k - _PHI)
                c3, s3 = math.cos(q3), math.sin(q3)
                q2 = _wrap(
                    math.atan2(z, rho) - math.atan2(A3 * s3 + D4 * c3, A2 + A3 * c3 - D4 * s3)
                )
                q23 = q2 + q3
                cb, sb = math.cos(q23), math.sin(q23)
                # M = Ry(q23) R' = R_36
                m02 = cb * a02 + sb * r22
                m12 = a12
                m22 = -sb * a02 + cb * r22
                m20 = -sb * a00 + cb * r20
                m21 = -sb * a01 + cb * r21
                s5 = math.sqrt(m02 * m02 + m12 * m12)
                q5 = math.atan2(s5, m22)
                if s5 > WRIST_SINGULAR_SIN:
                    q4 = math.atan2(-m12, -m02)
                    q6 = math.atan2(-m21, m20)
                else:
                    # Only q4 + q6 is defined: keep q4, give q6 the rest, exactly for this q5:
                    # Rz(q6) = Ry(q5) Rz(-q4) M, so q6 = atan2(X10, X00) of that product.
                    q4 = q4_seed
                    c4, s4 = math.cos(q4), math.sin(q4)
                    m00 = cb * a00 + sb * r20
                    m10 = a10
                    x00 = math.cos(q5) * (c4 * m00 + s4 * m10) + math.sin(q5) * m20
                    x10 = c4 * m10 - s4 * m00
                    q6 = math.atan2(x10, x00)
                rows.append([q1, q2, q3, q4, q5, q6])
                rows.append([q1, q2, q3, _wrap(q4 + PI), -q5, _wrap(q6 + PI)])
                reach += [True, True]
        return rows, reach

    def ik(self, T: FloatArray, seed: FloatArray) -> FloatArray:
        """The reachable solution within joint limits nearest ``seed`` (the current joints).

        Raises ``UnreachablePose`` when no configuration reaches ``T`` and
        ``JointLimitError`` when every one that does is past a limit.
        """
        ref = [float(x) for x in seed]
        # Fast path, exact: solve only the seed's shoulder/elbow branch (both wrists),
        # then bound the other branches from below by one angle each (the other elbow's
        # q3, the other shoulder's q1, both derived from this solution). When neither
        # bound can beat the best found, that solution is the nearest of all eight.
        rho_s, elbow_s, _ = _branch(ref)
        rows, reach = self._solve(T, seed, (rho_s,), (elbow_s,))
        if reach[0]:
            best_fast: list[float] | None = None
            cost = math.inf
            for row in rows:
                fitted = self._fit_row(row, ref)
                if fitted is not None and fitted[1] < cost:
                    best_fast, cost = fitted
            q1, q2, q3 = rows[0][0], rows[0][1], rows[0][2]
            q3_other = _wrap(-_wrap(q3 + _PHI) - _PHI)
            rho = _rho(q2, q3)
            q1_other = q1 + math.atan2(-D3, rho) - math.atan2(-D3, -rho)
            bound = min(_wrap(q3_other - ref[2]) ** 2, _wrap(q1_other - ref[0]) ** 2)
            if best_fast is not None and bound >= cost:
                return np.array(best_fast)
        rows, reach = self._solve(T, seed)
        # Each row's distance to the seed with every angle wrapped is a lower bound of
        # its distance once fitted into the limits: fit the rows in that order and stop
        # when no remaining row can win (usually after one).
        bounded = sorted(
            (sum(((a - r + PI) % TWO_PI - PI) ** 2 for a, r in zip(row, ref, strict=True)), i)
            for i, (row, ok) in enumerate(zip(rows, reach, strict=True))
            if ok
        )
        best: list[float] | None = None
        best_cost = math.inf
        for bound, i in bounded:
            if bound >= best_cost:
                break
            fitted = self._fit_row(rows[i], ref)
            if fitted is not None and fitted[1] < best_cost:
                best, best_cost = fitted
        if best is None:
            p = np.round(T[:3, 3], 4).tolist()
            if any(reach):
                raise JointLimitError(
                    f"every arm configuration reaching {p} m is past a joint limit"
                )
            raise UnreachablePose(f"the pose at {p} m is outside the PUMA 560's reach")
        return np.array(best)

    # ------------------------------------------------------------- labels
    @staticmethod
    def configuration(q: FloatArray) -> Configuration:
        c2, s2 = math.cos(q[1]), math.sin(q[1])
        c23, s23 = math.cos(q[1] + q[2]), math.sin(q[1] + q[2])
        rho = _rho(q[1], q[2])
        z = A2 * s2 + A3 * s23 + D4 * c23
        cross = rho * (A2 * s2) - z * (A2 * c2)  # (wrist) × (elbow) in the arm plane
        return Configuration(
            arm="right" if rho >= 0 else "left",
            elbow="up" if cross * rho > 0 else "down",
            wrist="noflip" if q[4] >= 0 else "flip",
        )
