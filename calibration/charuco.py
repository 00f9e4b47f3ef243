"""ChArUco calibration with OpenCV: intrinsics and distortion from views of a board,
then each camera's pose from the fiducials (solvePnP), and the stereo pair's relative
pose and baseline.

A ChArUco board is a chessboard whose white squares hold ArUco markers: every corner
found is identified, so partly hidden or tilted boards still give exact
correspondences. The board and its simulated views are in
``drivers/camera/charuco_board.py``, beside the simulated camera.
"""

from __future__ import annotations

import cv2
import numpy as np

from telerobot.calibration.model import CalibrationError, CameraModel, check_correspondences
from telerobot.drivers.base import FloatArray
from telerobot.drivers.camera.charuco_board import BoardSpec


def detect(image: np.ndarray, spec: BoardSpec) -> tuple[FloatArray, FloatArray] | None:
    """The board corners found in ``image``: (N, 3) board points and (N, 2) pixels."""
    board = spec.board()
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(image)
    if ids is None or len(ids) < 6:
        return None
    obj, img = board.matchImagePoints(corners, ids)  # type: ignore[call-overload]
    return np.asarray(obj, dtype=float).reshape(-1, 3), np.asarray(img, dtype=float).reshape(-1, 2)


def calibrate_intrinsics(
    views: list[np.ndarray], spec: BoardSpec, size: tuple[int, int]
) -> tuple[FloatArray, FloatArray, float, int]:
    """K, distortion, RMS reprojection error (px) and the number of views used."""
    obj, img = [], []
    for view in views:
        found = detect(view, spec)
        if found is not None:
            obj.append(found[0].astype(np.float32))
            img.append(found[1].astype(np.float32))
    if len(obj) < 4:
        raise CalibrationError(
            f"the board was found in {len(obj)} of {len(views)} views; at least 4 are needed "
            "(show the whole board, tilted differently each time)"
        )
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None)
    return np.asarray(K, dtype=float), np.asarray(dist, dtype=float).ravel(), float(rms), len(obj)


def fit_charuco(
    K: FloatArray,
    dist: FloatArray,
    points: FloatArray,
    pixels: FloatArray,
    camera: str,
    width: int,
    height: int,
) -> CameraModel:
    """The camera's pose from ≥ 4 fiducials with known intrinsics (solvePnP)."""
    X, uv = check_correspondences(points, pixels, at_least=4)
    ok, rvec, tvec = cv2.solvePnP(X, uv, K, dist, flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        raise CalibrationError("solvePnP found no pose for these fiducials: check the clicks")
    R, _ = cv2.Rodrigues(rvec)
    P = K @ np.hstack([R, tvec.reshape(3, 1)])
    return CameraModel.fitted(camera, "charuco", P, X, uv, width, height, K=K, dist=dist)


def extrinsics(model: CameraModel) -> tuple[FloatArray, FloatArray]:
    """World → camera R, t of a perspective model with known K."""
    if model.K is None:
        raise CalibrationError(f"the {model.method} model has no intrinsics")
    Rt = np.linalg.inv(model.K) @ model.P
    Rt = Rt / np.cbrt(np.linalg.det(Rt[:, :3]))
    return Rt[:, :3], Rt[:, 3]


def stereo_pose(left: CameraModel, right: CameraModel) -> tuple[FloatArray, FloatArray, float]:
    """The right camera's pose in the left camera's frame and the baseline (m)."""
    Rl, tl = extrinsics(left)
    Rr, tr = extrinsics(right)
    R = Rr @ Rl.T
    t = tr - R @ tl
    return R, t, float(np.linalg.norm(t))
