"""Camera calibration: the models the AR ball projects with, and how to make them.

Until a camera is calibrated the simulated camera's ground truth stands in (marked
as such). Fits are made from fiducials clicked in the camera's image (the browser's
calibration page, or a script), persist in the state folder and load at start.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Query
from pydantic import BaseModel, Field, field_validator

from telerobot.calibration.affine import fit_affine
from telerobot.calibration.charuco import calibrate_intrinsics, fit_charuco, stereo_pose
from telerobot.calibration.dlt import fit_dlt
from telerobot.calibration.model import CalibrationError, CameraModel
from telerobot.drivers.camera.charuco_board import BoardSpec, board_poses, render_view
from telerobot.drivers.sim.workcell import Workcell
from telerobot.server.api.deps import (
    CalibrationDep,
    IntrinsicsDep,
    MediaDep,
    OperatorDep,
    WorkcellDep,
)
from telerobot.server.api.requests import StrictRequest
from telerobot.server.media import rpc
from telerobot.server.services import CalibrationRecord, CameraName, Intrinsics

log = logging.getLogger(__name__)
router = APIRouter(prefix="/calibration", tags=["calibration"])


class CameraCalibration(BaseModel):
    name: str
    source: Literal["calibrated", "ground truth (simulation)"]
    method: str | None
    P: list[list[float]] = Field(description="3×4: pixel ~ P · [x, y, z, 1] (world = robot base)")
    width: int
    height: int
    rms_px: float | None
    max_px: float | None
    residuals_px: list[float] = []
    K: list[list[float]] | None = None
    dist: list[float] | None = None
    created: float | None = None


class CalibrationState(BaseModel):
    rig: str
    cameras: list[CameraCalibration]
    fiducials: list[list[float]] = Field(description="default 3D positions, in clicking order")
    baseline_m: float | None = Field(None, description="from the two cameras, when both have K")
    intrinsics_pending: list[str] = Field(
        [], description="cameras with ChArUco intrinsics waiting for a fiducial fit"
    )
    error: str | None = None


MAX_FIDUCIALS = 100  # clicked points per fit


class FitRequest(StrictRequest):
    camera: CameraName
    method: Literal["affine", "dlt", "charuco"] = "dlt"
    points: list[list[float]] = Field(
        description="fiducials' 3D positions (m, robot base)", max_length=MAX_FIDUCIALS
    )
    pixels: list[list[float]] = Field(
        description="where they were clicked, same order (u, v)", max_length=MAX_FIDUCIALS
    )

    @field_validator("points")
    @classmethod
    def _xyz(cls, v: list[list[float]]) -> list[list[float]]:
        if any(len(p) != 3 for p in v):
            raise ValueError("every point must be [x, y, z] (metres)")
        return v

    @field_validator("pixels")
    @classmethod
    def _uv(cls, v: list[list[float]]) -> list[list[float]]:
        if any(len(p) != 2 for p in v):
            raise ValueError("every pixel must be [u, v]")
        return v


class IntrinsicsResult(BaseModel):
    camera: CameraName
    K: list[list[float]]
    dist: list[float]
    rms_px: float
    views_used: int


def _camera(cell: Workcell, name: str) -> tuple[int, int]:
    cam = cell.rig.left if name == "left" else cell.rig.right
    return cam.width, cam.height


def state(record: CalibrationRecord, cell: Workcell, intrinsics: Intrinsics) -> CalibrationState:
    store = record.store
    cameras = []
    for truth in (cell.rig.left, cell.rig.right):
        model = store.cameras.get(truth.name)
        if model is None:
            cameras.append(
                CameraCalibration(
                    name=truth.name,
                    source="ground truth (simulation)",
                    method=None,
                    P=truth.P.tolist(),
                    width=truth.width,
                    height=truth.height,
                    rms_px=None,
                    max_px=None,
                )
            )
        else:
            d = model.to_json()
            cameras.append(CameraCalibration(name=truth.name, source="calibrated", **{
                k: d[k] for k in ("method", "P", "width", "height", "rms_px", "max_px",
                                  "residuals_px", "K", "dist", "created")
            }))  # fmt: skip
    baseline = None
    left, right = store.cameras.get("left"), store.cameras.get("right")
    if left is not None and right is not None and left.K is not None and right.K is not None:
        baseline = stereo_pose(left, right)[2]
    return CalibrationState(
        rig=store.rig,
        cameras=cameras,
        fiducials=cell.fiducials.tolist(),
        baseline_m=baseline,
        intrinsics_pending=intrinsics.pending(),
        error=record.load_error,
    )


@router.get("")
async def get_calibration(
    record: CalibrationDep, cell: WorkcellDep, intrinsics: IntrinsicsDep
) -> CalibrationState:
    return state(record, cell, intrinsics)


@router.post("/fit")
async def fit(
    body: FitRequest,
    record: CalibrationDep,
    cell: WorkcellDep,
    intrinsics: IntrinsicsDep,
    _op: OperatorDep,
) -> CalibrationState:
    """Fit one camera from clicked fiducials: ``affine`` (the thesis's 4 points),
    ``dlt`` (≥ 6 points, perspective), ``charuco`` (≥ 4 points, after
    /calibration/intrinsics). The result is kept and used by the AR view at once."""
    width, height = _camera(cell, body.camera)
    points, pixels = np.array(body.points, dtype=float), np.array(body.pixels, dtype=float)
    model: CameraModel
    if body.method == "affine":
        model = fit_affine(points, pixels, body.camera, width, height)
    elif body.method == "dlt":
        model = fit_dlt(points, pixels, body.camera, width, height)
    else:
        captured = intrinsics.get(body.camera)
        if captured is None:
            raise CalibrationError(
                f"no intrinsics for the {body.camera} camera yet: run the ChArUco capture "
                "(POST /api/v1/calibration/intrinsics) first"
            )
        K, dist = captured
        model = fit_charuco(K, dist, points, pixels, body.camera, width, height)
    await asyncio.to_thread(record.store.put, model)
    record.changed.emit(record.store)
    return state(record, cell, intrinsics)


@router.post("/intrinsics")
async def intrinsics(
    cell: WorkcellDep,
    captured: IntrinsicsDep,
    _op: OperatorDep,
    camera: CameraName,
    views: Annotated[int, Query(ge=4, le=40)] = 12,
    distance_m: Annotated[float, Query(gt=0.2, le=3.0)] = 0.9,
) -> IntrinsicsResult:
    """ChArUco intrinsics for one camera. On the simulation the camera is shown the
    board at ``views`` poses ``distance_m`` away and calibrated from what it sees."""
    truth = cell.rig.left if camera == "left" else cell.rig.right
    spec = BoardSpec()

    def run() -> tuple[np.ndarray, np.ndarray, float, int]:
        frames = [
            render_view(truth.K, truth.R, truth.t, (truth.width, truth.height), bR, bt, spec)
            for bR, bt in board_poses(truth.R, truth.t, distance_m, spec, views)
        ]
        return calibrate_intrinsics(frames, spec, (truth.width, truth.height))

    K, dist, rms, used = await asyncio.to_thread(run)
    captured.put(camera, K, dist)
    return IntrinsicsResult(
        camera=camera, K=K.tolist(), dist=dist.tolist(), rms_px=rms, views_used=used
    )


class BoardRequest(StrictRequest):
    view: int | None = Field(
        None, ge=0, le=99, description="which calibration pose; null puts the board away"
    )


@router.post("/board")
async def board(body: BoardRequest, media: MediaDep, _op: OperatorDep) -> BoardRequest:
    """On the simulation: hold the ChArUco board up in front of both cameras (in the
    live video) at calibration pose ``view``, for the page to capture. Real cameras:
    hold a printed board instead (this answers with an error saying so)."""
    await media.request(rpc.Board(body.view))
    return body


class ViewsRequest(StrictRequest):
    camera: CameraName
    images: list[str] = Field(
        description="views of the board from this camera: PNG or JPEG, base64 or data URLs",
        min_length=4,
        max_length=60,
    )


def decode_image(data: str) -> np.ndarray:
    import base64
    import binascii

    import cv2

    try:
        raw = base64.b64decode(data.split(",", 1)[-1], validate=True)
    except (binascii.Error, ValueError):
        raise CalibrationError("an image is not valid base64") from None
    if not raw:
        raise CalibrationError("an image is empty")
    try:
        image = cv2.imdecode(np.frombuffer(raw, np.uint8), cv2.IMREAD_GRAYSCALE)
    except cv2.error:
        image = None
    if image is None:
        raise CalibrationError("an image is not a PNG or JPEG the server can read")
    return np.asarray(image)


@router.post("/intrinsics/views")
async def intrinsics_from_views(
    body: ViewsRequest, cell: WorkcellDep, captured: IntrinsicsDep, _op: OperatorDep
) -> IntrinsicsResult:
    """ChArUco intrinsics and distortion from views captured by the page (real or
    simulated cameras alike); the fiducial fit with method ``charuco`` uses them."""
    width, height = _camera(cell, body.camera)
    # Decoding 60 views takes ~0.5 s: off the event loop (the e-stop's).
    views = await asyncio.to_thread(lambda: [decode_image(i) for i in body.images])
    sizes = {v.shape[::-1] for v in views}
    if sizes != {(width, height)}:
        raise CalibrationError(
            f"views must be {width}×{height} (the {body.camera} camera's image), got {sizes}"
        )
    K, dist, rms, used = await asyncio.to_thread(
        calibrate_intrinsics, views, BoardSpec(), (width, height)
    )
    captured.put(body.camera, K, dist)
    return IntrinsicsResult(
        camera=body.camera, K=K.tolist(), dist=dist.tolist(), rms_px=rms, views_used=used
    )


@router.delete("")
async def clear(
    record: CalibrationDep, cell: WorkcellDep, intrinsics: IntrinsicsDep, _op: OperatorDep
) -> CalibrationState:
    """Forget the calibration: the simulated ground truth stands in again."""
    await asyncio.to_thread(record.store.clear)
    intrinsics.clear()
    record.load_error = None
    record.changed.emit(record.store)
    return state(record, cell, intrinsics)
