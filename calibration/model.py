"""What every calibration method produces: a camera model that projects world points
(the robot's base frame, metres) to pixels, and how well it fits the points it was
fitted to."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from telerobot.drivers.base import FloatArray, InvalidCommand


class CalibrationError(InvalidCommand):
    """The input cannot give a camera model (too few points, coplanar, degenerate…)."""

    code = "calibration_error"


METHODS = ("affine", "dlt", "charuco")


@dataclass
class CameraModel:
    camera: str  # "left" / "right"
    method: str  # one of METHODS
    P: FloatArray  # 3×4; for the affine model the last row is [0, 0, 0, 1]
    residuals_px: FloatArray  # per fitted point
    width: int
    height: int
    K: FloatArray | None = None  # intrinsics, where the method finds them
    dist: FloatArray | None = None  # OpenCV distortion coefficients
    created: float = field(default_factory=time.time)

    @property
    def rms_px(self) -> float:
        return float(np.sqrt(np.mean(np.square(self.residuals_px))))

    @property
    def max_px(self) -> float:
        return float(np.max(self.residuals_px))

    @classmethod
    def fitted(
        cls, camera: str, method: str, P: FloatArray, X: FloatArray, uv: FloatArray,
        width: int, height: int, K: FloatArray | None = None, dist: FloatArray | None = None,
    ) -> CameraModel:  # fmt: skip
        """The model, with its residuals at the points it was fitted to."""
        model = cls(camera, method, P, np.zeros(len(X)), width, height, K=K, dist=dist)
        model.residuals_px = np.linalg.norm(model.project(X) - uv, axis=1)
        return model

    def project(self, points: FloatArray) -> FloatArray:
        """(N, 3) world points → (N, 2) pixels, through the lens distortion if known."""
        if self.K is None or self.dist is None or not np.any(self.dist):
            return project(self.P, points)
        import cv2

        Rt = np.linalg.inv(self.K) @ self.P
        Rt = Rt / np.cbrt(np.linalg.det(Rt[:, :3]))
        rvec, _ = cv2.Rodrigues(Rt[:, :3])
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        uv, _ = cv2.projectPoints(pts, rvec, Rt[:, 3], self.K, self.dist)
        return np.asarray(uv.reshape(-1, 2), dtype=float)

    def to_json(self) -> dict[str, Any]:
        return {
            "camera": self.camera,
            "method": self.method,
            "P": self.P.tolist(),
            "residuals_px": self.residuals_px.tolist(),
            "rms_px": self.rms_px,
            "max_px": self.max_px,
            "width": self.width,
            "height": self.height,
            "K": None if self.K is None else self.K.tolist(),
            "dist": None if self.dist is None else self.dist.tolist(),
            "created": self.created,
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> CameraModel:
        return cls(
            camera=str(d["camera"]),
            method=str(d["method"]),
            P=np.array(d["P"], dtype=float).reshape(3, 4),
            residuals_px=np.array(d["residuals_px"], dtype=float),
            width=int(d["width"]),
            height=int(d["height"]),
            K=None if d.get("K") is None else np.array(d["K"], dtype=float),
            dist=None if d.get("dist") is None else np.array(d["dist"], dtype=float),
            created=float(d.get("created", 0.0)),
        )


def project(P: FloatArray, points: FloatArray) -> FloatArray:
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    uvw = np.hstack([pts, np.ones((len(pts), 1))]) @ np.asarray(P, dtype=float).T
    return np.asarray(uvw[:, :2] / uvw[:, 2:3], dtype=float)


def check_correspondences(
    points: object, pixels: object, at_least: int
) -> tuple[FloatArray, FloatArray]:
    """(N, 3) world points and (N, 2) pixels as float arrays, or a clear error."""
    try:
        X = np.asarray(points, dtype=float)
        uv = np.asarray(pixels, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError("points and pixels must be lists of numbers") from None
    if X.ndim != 2 or X.shape[1] != 3:
        raise CalibrationError(f"points must be N×3 (x, y, z in metres), got shape {X.shape}")
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise CalibrationError(f"pixels must be N×2 (u, v), got shape {uv.shape}")
    if len(X) != len(uv):
        raise CalibrationError(f"{len(X)} points but {len(uv)} pixels: one click per point")
    if len(X) < at_least:
        raise CalibrationError(f"this method needs at least {at_least} points, got {len(X)}")
    if not (np.isfinite(X).all() and np.isfinite(uv).all()):
        raise CalibrationError("points and pixels must be finite numbers (no NaN)")
    return X, uv


def require_volume(points: FloatArray, why: str, at_least: float = 0.02) -> None:
    """Refuse points that (nearly) lie in one plane: ``why`` says what the method needs."""
    if spread(points) < at_least:
        raise CalibrationError(f"the points are (nearly) coplanar: {why}")


def spread(points: FloatArray) -> float:
    """How far from coplanar the points are: the smallest singular value of the
    centred points over the largest (0 = all in one plane, or on one line)."""
    s = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0
