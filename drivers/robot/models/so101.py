"""The SO-101 follower arm (TheRobotStudio's SO-ARM100 family, LeRobot's reference
arm): five revolute joints and a gripper, each a Feetech STS3215 bus servo.

The joint placements, axes and limits are the published description's ("new calib":
each joint's zero is the middle of its range), written here as numbers; the drawing
is primitives between the joints, no meshes. The tool frame is the description's
``gripper_frame_link``, between the jaws, so the default tool length is 0.

The gripper is a joint of the model (it is the sixth servo) but not of the tool's
chain: the IK keeps it where it is, and it moves by joint commands.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from telerobot.drivers.base import FloatArray
from telerobot.drivers.robot.models import RobotModel
from telerobot.drivers.robot.models.urdf import (
    Joint,
    Segment,
    chain_segments,
    origin_matrix,
    write_urdf,
)

if TYPE_CHECKING:
    from telerobot.drivers.robot.kinematics import ArmKinematics

PI = math.pi
JOINT_NAMES = ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll", "gripper")
TOOL_LINK = "gripper_frame_link"

JOINTS = (
    Joint(
        "shoulder_pan",
        "base_link",
        "shoulder_link",
        (0.0388353, 0.0, 0.0624),
        (PI, 0.0, -PI),
        limits=(-1.91986, 1.91986),
    ),
    Joint(
        "shoulder_lift",
        "shoulder_link",
        "upper_arm_link",
        (-0.0303992, -0.0182778, -0.0542),
        (-PI / 2, -PI / 2, 0.0),
        limits=(-1.74533, 1.74533),
    ),
    Joint(
        "elbow_flex",
        "upper_arm_link",
        "lower_arm_link",
        (-0.11257, -0.028, 0.0),
        (0.0, 0.0, PI / 2),
        limits=(-1.69, 1.69),
    ),
    Joint(
        "wrist_flex",
        "lower_arm_link",
        "wrist_link",
        (-0.1349, 0.0052, 0.0),
        (0.0, 0.0, -PI / 2),
        limits=(-1.65806, 1.65806),
    ),
    Joint(
        "wrist_roll",
        "wrist_link",
        "gripper_link",
        (0.0, -0.0611, 0.0181),
        (PI / 2, 0.0486795, PI),
        limits=(-2.74385, 2.84121),
    ),
    Joint(
        "gripper",
        "gripper_link",
        "moving_jaw_link",
        (0.0202, 0.0188, -0.0234),
        (PI / 2, 0.0, 0.0),
        limits=(-0.174533, 1.74533),
    ),
    Joint(
        TOOL_LINK + "_joint",
        "gripper_link",
        TOOL_LINK,
        (-0.0079, -0.000218121, -0.0981274),
        (0.0, PI, 0.0),
    ),
)


def _segments() -> list[Segment]:
    segments = chain_segments(JOINTS[:5], radius=0.015)
    # The fixed jaw to the tool point, and the moving jaw as long again from its hinge,
    # toward the tool point when closed.
    segments.append(Segment("gripper_link", (0.0, 0.0, 0.0), JOINTS[6].xyz, 0.012))
    hinge = origin_matrix(JOINTS[5].xyz, JOINTS[5].rpy)
    tip = np.linalg.inv(hinge) @ np.array([*JOINTS[6].xyz, 1.0])
    segments.append(Segment("moving_jaw_link", (0.0, 0.0, 0.0), tuple(tip[:3]), 0.008))
    return segments


SEGMENTS = tuple(_segments())
QLIM = np.array([j.limits for j in JOINTS[:6] if j.limits is not None], dtype=float)


def _kinematics(tool: FloatArray | None) -> ArmKinematics:
    from telerobot.drivers.robot.models.numeric import UrdfKinematics

    return UrdfKinematics(MODEL.urdf, TOOL_LINK, JOINT_NAMES, tool)


NAMED_POSES: dict[str, FloatArray] = {
    "zero": np.zeros(6),  # every joint mid-range: upper arm up, forearm and gripper forward
    # Reaching forward and down over the table, the gripper pointing down, half open.
    "ready": np.array([0.0, -0.6, 0.6, 1.2, 0.0, 0.5]),
    # Folded back on itself, as it is parked.
    "rest": np.array([0.0, -1.74, 1.66, 0.75, 0.0, 0.0]),
}

MODEL = RobotModel(
    name="so101",
    title="SO-101",
    urdf=write_urdf("so101", JOINTS, SEGMENTS),
    segments=SEGMENTS,
    joint_names=JOINT_NAMES,
    qlim=QLIM,
    flange=TOOL_LINK,
    named_poses=NAMED_POSES,
    home_pose="ready",
    start_pose="rest",
    # The STS3215 turns ~0.22 s per 60° unloaded at 12 V (4.7 rad/s): a margin below it.
    vmax=np.full(6, 3.0),
    amax=np.full(6, 10.0),
    stop_decel=np.full(6, 20.0),
    default_tool_length=0.0,
    make_kinematics=_kinematics,
    # At 0.4 of the PUMA's scene the table top is at the arm's base (where an SO-101 is
    # clamped) and the block 0.3 m in front of the shoulder; the workspace box is the
    # PUMA's box moved the same way.
    scene_scale=0.4,
    scene_offset=(0.0, 0.0, -0.16),
    pedestal_m=0.0,
    workspace_min=(-0.08, -0.32, -0.04),
    workspace_max=(0.42, 0.32, 0.48),
)
QLIM.setflags(write=False)
