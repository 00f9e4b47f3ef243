"""The simulated workcell's geometry and ground-truth cameras, for rendering,
calibration checks and the AR view."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel

from telerobot.drivers.sim.workcell import Box, PinholeCamera
from telerobot.server.api.deps import WorkcellDep

router = APIRouter(prefix="/workcell", tags=["workcell"])


class BoxModel(BaseModel):
    name: str
    centre: list[float]
    size: list[float]
    colour: tuple[int, int, int]


class CameraModel(BaseModel):
    name: str
    width: int
    height: int
    K: list[list[float]]
    R: list[list[float]]
    t: list[float]
    P: list[list[float]]
    position: list[float]


class WorkcellModel(BaseModel):
    boxes: list[BoxModel]
    fiducials: list[list[float]]
    cameras: list[CameraModel]
    baseline: float


def _box(b: Box) -> BoxModel:
    return BoxModel(name=b.name, centre=b.centre.tolist(), size=b.size.tolist(), colour=b.colour)


def _camera(c: PinholeCamera) -> CameraModel:
    return CameraModel(
        name=c.name,
        width=c.width,
        height=c.height,
        K=c.K.tolist(),
        R=c.R.tolist(),
        t=c.t.tolist(),
        P=c.P.tolist(),
        position=c.position.tolist(),
    )


@router.get("")
async def workcell(cell: WorkcellDep) -> WorkcellModel:
    return WorkcellModel(
        boxes=[_box(b) for b in cell.obstacles],
        fiducials=cell.fiducials.tolist(),
        cameras=[_camera(cell.rig.left), _camera(cell.rig.right)],
        baseline=cell.rig.baseline,
    )
