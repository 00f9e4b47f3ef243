"""How far the AR ball lands from the gripper, per calibration method.

    python -m bench.ar_registration [--json]

On the simulation at 1280×720, cameras 1.5, 2.5 and 4 m from the work centre: each
method is fitted from simulated clicks on the fiducials (the ground-truth projection
rounded to the nearest pixel, as a careful operator with zoom clicks), then the
gripper is swept over a grid across the work area (0.45–0.95 m × −0.45–0.35 m ×
0.42–0.75 m above the base, 6 × 6 × 4 points) and each model's projection is
compared with the ground-truth camera's, in both cameras. Methods:

- ``affine``: the thesis's weak-perspective model from its 4 fiducials (§5.3);
- ``dlt``: perspective, from the 8 fiducials (DLT + Levenberg–Marquardt);
- ``charuco``: intrinsics from 12 simulated views of a ChArUco board, then the pose
  from the 8 fiducials (solvePnP).
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np

from bench.common import emit, machine, parser
from harness.work_area import work_area
from telerobot.calibration.affine import fit_affine
from telerobot.calibration.charuco import calibrate_intrinsics, fit_charuco
from telerobot.calibration.dlt import fit_dlt
from telerobot.calibration.model import CameraModel
from telerobot.drivers.camera.charuco_board import BoardSpec, board_poses, render_view
from telerobot.drivers.sim.workcell import PinholeCamera, default_workcell

DISTANCES = (1.5, 2.5, 4.0)


def fit(method: str, cam: PinholeCamera, fiducials: np.ndarray) -> CameraModel:
    clicks = np.round(cam.project(fiducials))
    if method == "affine":
        return fit_affine(fiducials[:4], clicks[:4], cam.name, cam.width, cam.height)
    if method == "dlt":
        return fit_dlt(fiducials, clicks, cam.name, cam.width, cam.height)
    spec = BoardSpec()
    size = (cam.width, cam.height)
    views = [
        render_view(cam.K, cam.R, cam.t, size, bR, bt, spec)
        for bR, bt in board_poses(cam.R, cam.t, 0.9, spec, 12)
    ]
    K, dist, _, _ = calibrate_intrinsics(views, spec, size)
    return fit_charuco(K, dist, fiducials, clicks, cam.name, cam.width, cam.height)


def main() -> None:
    args = parser(__doc__ or "").parse_args()
    grid = work_area()
    figures: dict[str, Any] = {}
    detail: dict[str, Any] = {}
    for method in ("affine", "dlt", "charuco"):
        figures[method] = {}
        for distance in DISTANCES:
            cell = default_workcell(camera_distance=distance, width=1280, height=720)
            errors, fit_rms, t0 = [], [], time.perf_counter()
            for cam in (cell.rig.left, cell.rig.right):
                model = fit(method, cam, cell.fiducials)
                errors.append(np.linalg.norm(model.project(grid) - cam.project(grid), axis=1))
                fit_rms.append(model.rms_px)
            e = np.concatenate(errors)
            key = f"{distance:g}"
            figures[method][key] = {
                "median_px": float(np.median(e)),
                "p95_px": float(np.percentile(e, 95)),
            }
            detail[f"{method}@{key}m"] = (
                f"median {np.median(e):.2f} px, p95 {np.percentile(e, 95):.2f} px, "
                f"max {e.max():.2f} px, fit rms {np.mean(fit_rms):.2f} px, "
                f"{time.perf_counter() - t0:.2f} s"
            )
    emit(detail, False)
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
