"""The ChArUco board, and drawing it into a simulated camera's view: the simulation
holds a board up in front of its cameras (for the page's capture) and renders views
of it (for scripted intrinsics), so the calibration flow runs without hardware.

A ChArUco board is a chessboard whose white squares hold ArUco markers. The board is
a plane, so a view of it at any pose is one homography of the printed image. Fitting
(detection, intrinsics, poses) is in ``calibration/charuco.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from telerobot.drivers.base import FloatArray


@dataclass(frozen=True)
class BoardSpec:
    squares_x: int = 9
    squares_y: int = 6
    square_m: float = 0.04
    marker_m: float = 0.03
    dictionary: int = cv2.aruco.DICT_4X4_50

    def board(self) -> cv2.aruco.CharucoBoard:
        return cv2.aruco.CharucoBoard(
            (self.squares_x, self.squares_y),
            self.square_m,
            self.marker_m,
            cv2.aruco.getPredefinedDictionary(self.dictionary),
        )

    @property
    def size_m(self) -> tuple[float, float]:
        return self.squares_x * self.square_m, self.squares_y * self.square_m


def board_image(spec: BoardSpec, px_per_square: int = 100) -> np.ndarray:
    """The printable board, grey levels, one pixel = square_m / px_per_square."""
    size = (spec.squares_x * px_per_square, spec.squares_y * px_per_square)
    return np.asarray(spec.board().generateImage(size, marginSize=0, borderBits=1))


def _board_homography(
    K: FloatArray, R: FloatArray, t: FloatArray, board_R: FloatArray, board_t: FloatArray,
    spec: BoardSpec, px: int,
) -> FloatArray:  # fmt: skip
    metres_per_px = spec.square_m / px
    S = np.diag([metres_per_px, metres_per_px, 1.0])  # board pixels → board metres
    Rc = R @ board_R  # board → camera
    tc = R @ board_t + t
    return np.asarray(K @ np.column_stack([Rc[:, 0], Rc[:, 1], tc]) @ S, dtype=float)


def draw_board(
    image: np.ndarray,
    K: FloatArray,
    R: FloatArray,
    t: FloatArray,
    board_R: FloatArray,
    board_t: FloatArray,
    spec: BoardSpec,
) -> None:
    """Paint the board, as a pinhole camera (K, world→camera R, t) sees it, into
    ``image`` (grey or RGB, in place). The board lies at world pose (board_R, board_t):
    its x, y axes along the printed image's columns and rows, z into the print (so the
    printed side faces −z)."""
    px = 100
    board = board_image(spec, px)
    H = _board_homography(K, R, t, board_R, board_t, spec, px)
    size = (image.shape[1], image.shape[0])
    warped = cv2.warpPerspective(board, H, size, flags=cv2.INTER_AREA)
    mask = cv2.warpPerspective(np.full_like(board, 255), H, size, flags=cv2.INTER_NEAREST) > 0
    image[mask] = warped[mask][:, None] if image.ndim == 3 else warped[mask]


def render_view(
    K: FloatArray,
    R: FloatArray,
    t: FloatArray,
    size: tuple[int, int],
    board_R: FloatArray,
    board_t: FloatArray,
    spec: BoardSpec,
    background: int = 110,
) -> np.ndarray:
    """The board alone on a grey background, as the camera sees it (see draw_board)."""
    image = np.full((size[1], size[0]), background, np.uint8)
    draw_board(image, K, R, t, board_R, board_t, spec)
    return image


def view_distance(K: FloatArray, width: int, spec: BoardSpec, fill: float = 0.45) -> float:
    """How far from the camera the board spans ``fill`` of the image's width."""
    return float(K[0, 0] * spec.size_m[0] / (fill * width))


def _rotation(rx: float, ry: float, rz: float) -> FloatArray:
    R, _ = cv2.Rodrigues(np.array([rx, ry, rz], dtype=float))
    return np.asarray(R, dtype=float)


def board_poses(
    R: FloatArray, t: FloatArray, distance: float, spec: BoardSpec, views: int = 12, seed: int = 0
) -> list[tuple[FloatArray, FloatArray]]:
    """World poses that put the board ~``distance`` in front of a camera (R, t), facing it,
    tilted up to ±35° and spread over the image: a good set of calibration views."""
    rng = np.random.default_rng(seed)
    w, h = spec.size_m
    poses = []
    for i in range(views):
        tilt = _rotation(
            math.radians(rng.uniform(-35, 35)),
            math.radians(rng.uniform(-35, 35)),
            math.radians(rng.uniform(-20, 20)),
        )
        Rc = tilt  # board x right, y down, z into the print: the print faces the camera
        centre = np.array(
            [rng.uniform(-0.25, 0.25) * distance, rng.uniform(-0.15, 0.15) * distance,
             distance * rng.uniform(0.8, 1.2)]
        )  # fmt: skip
        tc = centre - Rc @ np.array([w / 2, h / 2, 0.0])
        # camera pose → world: board_R = Rᵀ Rc, board_t = Rᵀ (tc − t)
        poses.append((R.T @ Rc, R.T @ (tc - t)))
        del i
    return poses
