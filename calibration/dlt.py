"""Full perspective from six or more points: the Direct Linear Transform (Hartley's
normalised form), then refined by Levenberg–Marquardt on the reprojection error.

The DLT solves P (3×4, up to scale) from x × (P X) = 0 by SVD after moving the
points to zero mean and unit spread (without that, pixel coordinates in the hundreds
and metres near one make the system badly conditioned). The refinement then
minimises the sum of squared pixel errors, which is what the operator sees.
"""

from __future__ import annotations

import numpy as np

from telerobot.calibration.model import (
    CalibrationError,
    CameraModel,
    check_correspondences,
    project,
    require_volume,
)
from telerobot.drivers.base import FloatArray


def _normaliser(points: FloatArray) -> FloatArray:
    """A similarity moving ``points`` to zero mean and mean distance √d."""
    d = points.shape[1]
    mean = points.mean(axis=0)
    scale = np.sqrt(d) / max(np.mean(np.linalg.norm(points - mean, axis=1)), 1e-12)
    T = np.eye(d + 1)
    T[:d, :d] *= scale
    T[:d, d] = -scale * mean
    return T


def dlt(X: FloatArray, uv: FloatArray) -> FloatArray:
    T3, T2 = _normaliser(X), _normaliser(uv)
    Xn = np.hstack([X, np.ones((len(X), 1))]) @ T3.T
    un = np.hstack([uv, np.ones((len(uv), 1))]) @ T2.T
    rows = []
    for Xi, (u, v, w) in zip(Xn, un, strict=True):
        zero = np.zeros(4)
        rows.append(np.hstack([zero, -w * Xi, v * Xi]))
        rows.append(np.hstack([w * Xi, zero, -u * Xi]))
    _, s, vt = np.linalg.svd(np.array(rows))
    if s[-2] < 1e-9 * s[0]:
        raise CalibrationError("the points do not determine a camera (a degenerate set)")
    Pn = vt[-1].reshape(3, 4)
    P = np.linalg.inv(T2) @ Pn @ T3
    return np.asarray(P / np.linalg.norm(P), dtype=float)


def refine(P: FloatArray, X: FloatArray, uv: FloatArray, iterations: int = 50) -> FloatArray:
    """Levenberg–Marquardt on the 12 entries of P (kept at unit norm)."""
    p = P.ravel().copy()
    lam = 1e-3

    def residuals(q: FloatArray) -> FloatArray:
        return (project(q.reshape(3, 4), X) - uv).ravel()

    r = residuals(p)
    for _ in range(iterations):
        J = np.empty((len(r), 12))
        for j in range(12):
            h = 1e-7 * max(1.0, abs(p[j]))
            q = p.copy()
            q[j] += h
            J[:, j] = (residuals(q) - r) / h
        A, g = J.T @ J, J.T @ r
        while True:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            q = p + step
            q /= np.linalg.norm(q)
            rq = residuals(q)
            if rq @ rq < r @ r:
                p, r, lam = q, rq, max(lam / 10, 1e-12)
                break
            lam *= 10
            if lam > 1e8:
                return p.reshape(3, 4)
        if np.linalg.norm(step) < 1e-12:
            break
    return p.reshape(3, 4)


def fit_dlt(
    points: FloatArray, pixels: FloatArray, camera: str, width: int, height: int
) -> CameraModel:
    X, uv = check_correspondences(points, pixels, at_least=6)
    require_volume(X, "a perspective fit needs points off one plane")
    P = refine(dlt(X, uv), X, uv)
    # Points in front of the camera have w > 0 (the sign of P is free: fix it).
    w = np.hstack([X, np.ones((len(X), 1))]) @ P[2]
    if np.all(w < 0):
        P = -P
    elif not np.all(w > 0):
        raise CalibrationError("the fit puts some points behind the camera: check the clicks")
    return CameraModel.fitted(camera, "dlt", P, X, uv, width, height)
