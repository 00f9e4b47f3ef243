"""Robot state and model. Motion endpoints arrive with the DecisionServer, so that
every motion command goes through one safety path."""

from __future__ import annotations

import math

from fastapi import APIRouter
from pydantic import BaseModel

from backend.api.deps import RobotDep, SettingsDep
from drivers.base import RobotStatus, WorkingFrame
from drivers.robot.puma560.kinematics import DH, NAMED_POSES, QLIM_DEG

router = APIRouter(prefix="/robot", tags=["robot"])


class RobotState(BaseModel):
    driver: str
    status: RobotStatus
    message: str
    joints: list[float]  # radians, corrected
    joints_deg: list[float]
    position: list[float]  # tool position in the base frame, metres
    rotation: list[list[float]]  # tool orientation matrix, base frame
    frame: WorkingFrame


class DHRow(BaseModel):
    d: float
    a: float
    alpha: float


class RobotModel(BaseModel):
    name: str
    dh: list[DHRow]  # standard DH: Rz(q) Tz(d) Tx(a) Rx(alpha)
    joint_limits_deg: list[tuple[float, float]]
    named_poses: dict[str, list[float]]
    tool: list[list[float]]  # flange → tool, 4×4
    home_pose: str


@router.get("/state")
async def state(robot: RobotDep) -> RobotState:
    q = robot.joints
    pose = robot.pose
    return RobotState(
        driver=robot.name,
        status=robot.status,
        message=robot.status_message,
        joints=q.tolist(),
        joints_deg=[math.degrees(a) for a in q],
        position=pose.position.tolist(),
        rotation=pose.rotation.tolist(),
        frame=robot.frame,
    )


@router.get("/model")
async def model(robot: RobotDep, settings: SettingsDep) -> RobotModel:
    kin = getattr(robot, "kinematics", None)
    tool = (
        kin.tool.tolist()
        if kin is not None
        else [[float(i == j) for j in range(4)] for i in range(4)]
    )
    return RobotModel(
        name="PUMA 560",
        dh=[DHRow(d=d, a=a, alpha=alpha) for d, a, alpha in DH],
        joint_limits_deg=[(float(lo), float(hi)) for lo, hi in QLIM_DEG],
        named_poses={k: v.tolist() for k, v in NAMED_POSES.items()},
        tool=tool,
        home_pose=settings.home_pose,
    )
