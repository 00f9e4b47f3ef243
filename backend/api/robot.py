"""Robot state, model, initialisation and scripted moves. Every move goes through
the DecisionServer (lease, limits, e-stop), like the real-time channel's commands."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Body, Query, Response
from pydantic import BaseModel, Field

from telerobot.drivers.base import DeviceError, InvalidCommand, Robot, RobotStatus, WorkingFrame
from telerobot.server.api.deps import ArmDep, ClientDep, DecisionDep, DriverClientDep, ServicesDep
from telerobot.server.api.requests import StrictRequest
from telerobot.server.control.errors import StillMoving
from telerobot.server.settings import SINGLE_ARM

router = APIRouter(prefix="/robot", tags=["robot"])


class RobotState(BaseModel):
    arm: str  # its name ("arm" on a one-arm server; GET /robot/arms)
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


class ArmInfo(BaseModel):
    name: str  # what ``?arm=`` takes
    index: int  # on the wire (CART_INC's arm; 1 for the first)
    model: str  # its model's settings name: puma560, so101
    driver: str
    dof: int
    status: RobotStatus
    # Where its base stands in the workcell (4×4): each arm's commands, state and
    # workspace are in its own base frame; this places them in one scene.
    mount: list[list[float]]


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


def robot_state(robot: Robot, frame: WorkingFrame, arm: str = SINGLE_ARM) -> RobotState:
    q = robot.joints
    pose = robot.pose
    return RobotState(
        arm=arm,
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


@router.get("/arms")
async def arms(services: ServicesDep) -> list[ArmInfo]:
    """The arms this server drives, in order (one, named "arm", unless the settings
    name more: docs/arms.md)."""
    return [
        ArmInfo(
            name=a.name,
            index=i + 1,
            model=a.settings.robot_model,
            driver=a.robot.name,
            dof=a.settings.model.dof,
            status=a.robot.status,
            mount=a.mount.tolist(),
        )
        for i, a in enumerate(services.arms)
    ]


@router.get("/state")
async def state(arm: ArmDep, decision: DecisionDep) -> RobotState:
    return robot_state(arm.robot, decision.frame, arm.name)


@router.get("/diagnostics")
async def diagnostics(arm: ArmDep) -> dict[str, Any]:
    """The driver's view of the hardware: for the SO-101 each servo's position, speed,
    load, voltage, temperature, error bits and missed reads, the bus's read rate and
    how long goals wait for it (``goal_to_bus_ms``); only ``driver`` for the simulation."""
    return {"driver": arm.robot.name, **arm.robot.diagnostics()}


@router.get("/model")
async def model(arm: ArmDep) -> RobotModel:
    """The arm's model: the page computes its kinematics and draws it from this;
    ``/robot/model.urdf`` is the same arm as URDF."""
    robot, settings = arm.robot, arm.settings
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
async def model_urdf(arm: ArmDep) -> Response:
    """The arm as URDF (primitives only), for URDF tools (RViz, Foxglove,
    urdf-loader). The tool set on the server is not in it: it is ``/robot/model``'s."""
    return Response(arm.settings.model.urdf, media_type="application/xml")


@router.post("/initialize")
async def initialize(
    arm: ArmDep,
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
            client.id, None if joints is None else np.array(joints, dtype=float), arm=arm.name
        )
    finally:
        client.busy -= 1
        decision.seen(client.id)
    return robot_state(arm.robot, decision.frame, arm.name)


def _need(value: list[float] | None, what: str) -> np.ndarray:
    if value is None:
        raise InvalidCommand(f"this move needs {what}")
    return np.array(value, dtype=float)


@router.post("/move")
async def move(
    body: MoveRequest, arm: ArmDep, decision: DecisionDep, client: DriverClientDep
) -> MoveResult:
    """A scripted move of the arm (``?arm=``), absolute or incremental, in joint or
    Cartesian space (its own base frame). With ``wait`` it returns when the motion
    has ended (or fails); otherwise at once."""
    robot, name = arm.robot, arm.name
    if body.space == "joint" and body.mode == "absolute":
        applied = await decision.move_joints(client.id, _need(body.joints, "joints"), arm=name)
    elif body.space == "joint":
        applied = await decision.joint_increment(
            client.id, _need(body.joints, "joints (increments)"), arm=name
        )
    elif body.mode == "absolute":
        rotation = (
            robot.pose.rotation if body.rotation is None else np.array(body.rotation, dtype=float)
        )
        applied = await decision.move_pose(
            client.id, _need(body.position, "position"), rotation, arm=name
        )
    else:
        dX = np.zeros(3) if body.position is None else np.array(body.position, dtype=float)
        rv = np.zeros(3) if body.rotvec is None else np.array(body.rotvec, dtype=float)
        applied = await decision.cartesian_increment(client.id, dX, rv, frame=body.frame, arm=name)
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
        state=robot_state(robot, decision.frame, name),
    )


@router.post("/stop")
async def stop(
    services: ServicesDep,
    decision: DecisionDep,
    client: DriverClientDep,
    arm: Annotated[
        str | None, Query(max_length=32, description="which arm; none: every arm stops")
    ] = None,
) -> list[RobotState]:
    """Stop the current motion of the arm named, or of every arm (not latched; the
    e-stop is /safety/estop). One state for each arm stopped."""
    chosen = services.arms if arm is None else [services.arms[decision.arm(arm).index - 1]]
    for a in chosen:
        await a.robot.stop()
    return [robot_state(a.robot, decision.frame, a.name) for a in chosen]


@router.put("/joint-offsets")
async def set_joint_offsets(
    body: JointOffsets, arm: ArmDep, decision: DecisionDep, client: ClientDep
) -> RobotState:
    if decision.lease_holder != client.id:
        raise InvalidCommand("take the control lease before changing joint corrections")
    arm.robot.joint_offsets = np.array(body.offsets, dtype=float)
    return robot_state(arm.robot, decision.frame, arm.name)
