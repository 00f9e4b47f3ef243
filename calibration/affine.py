"""The thesis's camera identification (§5.2–5.3, eq. 5.9–5.17): a weak-perspective
(affine) model p = M·P + p0 from four non-coplanar fiducials and their clicked pixels.

With the first point as the origin of the affine frame, the other three span a basis:
M = [p1−p0, p2−p0, p3−p0] · [P1−P0, P2−P0, P3−P0]⁻¹ (the thesis's closed form of
eq. 5.17), and the offset is p0 − M·P0. More than four points are fitted by least
squares. Cheap and robust, but it ignores perspective: points off the basis' depth
land tens of pixels away (docs/PERFORMANCE.md, bench.ar_registration).
"""

from __future__ import annotations

import numpy as np

from telerobot.calibration.model import CameraModel, check_correspondences, require_volume
from telerobot.drivers.base import FloatArray


def fit_affine(
    points: FloatArray, pixels: FloatArray, camera: str, width: int, height: int
) -> CameraModel:
    X, uv = check_correspondences(points, pixels, at_least=4)
    require_volume(
        X,
        "the affine method needs four points that span a volume (the origin and one "
        "point along each of x, y and z)",
    )
    if len(X) == 4:
        basis = (X[1:] - X[0]).T  # columns: P1−P0, P2−P0, P3−P0
        image = (uv[1:] - uv[0]).T
        M = image @ np.linalg.inv(basis)
        p0 = uv[0] - M @ X[0]
    else:
        A = np.hstack([X, np.ones((len(X), 1))])
        sol, *_ = np.linalg.lstsq(A, uv, rcond=None)  # (4, 2): [Mᵀ; p0]
        M, p0 = sol[:3].T, sol[3]
    P = np.vstack([np.hstack([M, p0[:, None]]), [0.0, 0.0, 0.0, 1.0]])
    return CameraModel.fitted(camera, "affine", P, X, uv, width, height)
