"""Robot state, model, initialisation and scripted moves. Every move goes through
the DecisionServer (lease, limits, e-stop), like the real-time channel's commands."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Body, Response
from pydantic import BaseModel, Field

from telerobot.drivers.base import DeviceError, InvalidCommand, Robot, RobotStatus, WorkingFrame
from telerobot.server.api.deps import ClientDep, DecisionDep, RobotDep, SettingsDep
from telerobot.server.api.requests import StrictRequest
from telerobot.server.control.decision import StillMoving

router = APIRouter(prefix="/robot", tags=["robot"])


class RobotState(BaseModel):
    driver: str
    status: RobotStatus
    message: str
    joints: list[float]  # radians, corrected
    joints_deg: list[float]
    position: list[float]  # tool position in the base frame, metres
    rotation: list[list[float]]  # tool orientation matrix, base frame
    target_joints: list[float]  # last commanded target, radians
    joint_offsets: list[float]  # model angle = controller angle + offset, radians
    frame: WorkingFrame


class ModelJoint(BaseModel):
    """A revolute joint: its frame is the parent joint's (the base's for -1) times
    ``origin`` times a rotation of q about ``axis``."""

    name: str
    parent: int  # index into ``joints``; -1: the base
    origin: list[list[float]]  # 4×4, in the parent joint's frame
    axis: list[float]  # unit vector in the joint's frame


class ModelFlange(BaseModel):
    parent: int  # the joint the tool is mounted on (index into ``joints``)
    origin: list[list[float]]  # 4×4, in that joint's frame


class RobotModel(BaseModel):
    model: str  # the settings' name: puma560, so101
    name: str  # for a person: "PUMA 560", "SO-101"
    dof: int
    joint_names: list[str]
    joints: list[ModelJoint]  # the kinematic tree, in joint order
    flange: ModelFlange
    joint_limits_deg: list[tuple[float, float]]
    named_poses: dict[str, list[float]]
    tool: list[list[float]]  # flange → tool, 4×4
    home_pose: str
    urdf: str  # where the description is, as URDF (for URDF tools)


class InitializeRequest(StrictRequest):
    joints: list[float] | None = Field(None, description="radians; default: the home pose")


class MoveRequest(StrictRequest):
    space: Literal["joint", "cartesian"]
    mode: Literal["absolute", "incremental"]
    joints: list[float] | None = Field(
        None,
        description="joint space: one angle or increment per joint (GET /robot/model), radians",
    )
    position: list[float] | None = Field(None, description="cartesian: position or ΔX, metres")
    rotation: list[list[float]] | None = Field(
        None,
        description="cartesian absolute: 3×3 orientation matrix (default: keep the current one)",
    )
    rotvec: list[float] | None = Field(
        None, description="cartesian incremental: ΔM as a rotation vector, radians"
    )
    frame: WorkingFrame | None = Field(
        None, description="frame of an increment (default: the working frame)"
    )
    wait: bool = Field(
        True, description="return when the motion has ended (else at once; poll /robot/state)"
    )
    timeout_s: float = Field(60.0, gt=0, le=600)


class MoveResult(BaseModel):
    limited: bool  # the speed limit scaled an increment down
    target_joints: list[float]
    state: RobotState


class JointOffsets(StrictRequest):
    offsets: list[float] = Field(description="radians: model angle = controller angle + offset")


def robot_state(robot: Robot, frame: WorkingFrame) -> RobotState:
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
        target_joints=robot.target_joints.tolist(),
        joint_offsets=robot.joint_offsets.tolist(),
        frame=frame,
    )


@router.get("/state")
async def state(robot: RobotDep, decision: DecisionDep) -> RobotState:
    return robot_state(robot, decision.frame)


@router.get("/diagnostics")
async def diagnostics(robot: RobotDep) -> dict[str, Any]:
    """The driver's view of the hardware: for the SO-101 each servo's position, speed,
    load, voltage, temperature, error bits and missed reads, the bus's read rate and
    how long goals wait for it (``goal_to_bus_ms``); only ``driver`` for the simulation."""
    return {"driver": robot.name, **robot.diagnostics()}


@router.get("/model")
async def model(robot: RobotDep, settings: SettingsDep) -> RobotModel:
    """The connected arm's model: the page computes its kinematics and draws it from
    this; ``/robot/model.urdf`` is the same arm as URDF."""
    description = settings.model
    chain = description.chain()
    return RobotModel(
        model=description.name,
        name=description.title,
        dof=description.dof,
        joint_names=list(description.joint_names),
        joints=[ModelJoint.model_validate(j) for j in chain["joints"]],
        flange=ModelFlange.model_validate(chain["flange"]),
        joint_limits_deg=[(math.degrees(lo), math.degrees(hi)) for lo, hi in description.qlim],
        named_poses={k: v.tolist() for k, v in description.named_poses.items()},
        tool=robot.kinematics.tool.tolist(),
        home_pose=settings.home_pose_name,
        urdf="/api/v1/robot/model.urdf",
    )


@router.get(
    "/model.urdf",
    response_class=Response,
    responses={200: {"content": {"application/xml": {}}, "description": "the arm as URDF"}},
)
async def model_urdf(settings: SettingsDep) -> Response:
    """The connected arm as URDF (primitives only), for URDF tools (RViz, Foxglove,
    urdf-loader). The tool set on the server is not in it: it is ``/robot/model``'s."""
    return Response(settings.model.urdf, media_type="application/xml")


@router.post("/initialize")
async def initialize(
    robot: RobotDep,
    decision: DecisionDep,
    client: ClientDep,
    body: Annotated[InitializeRequest | None, Body()] = None,
) -> RobotState:
    """Connect if needed, prepare the arm and move it to ``joints`` (default: home).
    Returns when the arm is READY. The body is optional: none (``curl -X POST``) is
    ``{}``, the home pose."""
    joints = None if body is None else body.joints
    client.busy += 1
    try:
        await decision.initialize(
            client.id, None if joints is None else np.array(joints, dtype=float)
        )
    finally:
        client.busy -= 1
        decision.seen(client.id)
    return robot_state(robot, decision.frame)


def _need(value: list[float] | None, what: str) -> np.ndarray:
    if value is None:
        raise InvalidCommand(f"this move needs {what}")
    return np.array(value, dtype=float)


@router.post("/move")
async def move(
    body: MoveRequest, robot: RobotDep, decision: DecisionDep, client: ClientDep
) -> MoveResult:
    """A scripted move, absolute or incremental, in joint or Cartesian space. With
    ``wait`` it returns when the motion has ended (or fails); otherwise at once."""
    if body.space == "joint" and body.mode == "absolute":
        applied = await decision.move_joints(client.id, _need(body.joints, "joints"))
    elif body.space == "joint":
        applied = await decision.joint_increment(
            client.id, _need(body.joints, "joints (increments)")
        )
    elif body.mode == "absolute":
        rotation = (
            robot.pose.rotation if body.rotation is None else np.array(body.rotation, dtype=float)
        )
        applied = await decision.move_pose(client.id, _need(body.position, "position"), rotation)
    else:
        dX = np.zeros(3) if body.position is None else np.array(body.position, dtype=float)
        rv = np.zeros(3) if body.rotvec is None else np.array(body.rotvec, dtype=float)
        applied = await decision.cartesian_increment(client.id, dX, rv, frame=body.frame)
    if body.wait:
        client.busy += 1
        try:
            await robot.wait_idle(body.timeout_s)
        except TimeoutError:
            raise StillMoving(
                f"the arm is still moving after {body.timeout_s:g} s; poll /api/v1/robot/state "
                "or stop it with /api/v1/robot/stop"
            ) from None
        finally:
            client.busy -= 1
            decision.seen(client.id)
        if robot.status is RobotStatus.ERROR:
            raise DeviceError(f"the move failed: {robot.status_message}")
    return MoveResult(
        limited=applied.limited,
        target_joints=applied.target.tolist(),
        state=robot_state(robot, decision.frame),
    )


@router.post("/stop")
async def stop(robot: RobotDep, decision: DecisionDep, client: ClientDep) -> RobotState:
    """Stop the current motion (not latched; the e-stop is /safety/estop)."""
    await robot.stop()
    return robot_state(robot, decision.frame)


@router.put("/joint-offsets")
async def set_joint_offsets(
    body: JointOffsets, robot: RobotDep, decision: DecisionDep, client: ClientDep
) -> RobotState:
    if decision.lease_holder != client.id:
        raise InvalidCommand("take the control lease before changing joint corrections")
    robot.joint_offsets = np.array(body.offsets, dtype=float)
    return robot_state(robot, decision.frame)
