"""The PUMA 560 as a model: its URDF generated from the DH table the closed-form
kinematics uses, so the page and any URDF tool draw the same arm the IK solves."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from telerobot.drivers.base import FloatArray
from telerobot.drivers.robot.models import RobotModel
from telerobot.drivers.robot.models.urdf import dh_chain, write_urdf
from telerobot.drivers.robot.motion import PUMA_AMAX, PUMA_STOP_DECEL, PUMA_VMAX
from telerobot.drivers.robot.puma560.geometry import DH, NAMED_POSES, QLIM

if TYPE_CHECKING:
    from telerobot.drivers.robot.kinematics import ArmKinematics


def _kinematics(tool: FloatArray | None) -> ArmKinematics:
    # Pinocchio only when the kinematics are asked for: a client-only install reads
    # the model (the joint mirror's limits) without it.
    from telerobot.drivers.robot.puma560.kinematics import Puma560Kinematics

    return Puma560Kinematics(tool)


_joints, _segments = dh_chain(DH, QLIM, radius=0.05)

MODEL = RobotModel(
    name="puma560",
    title="PUMA 560",
    urdf=write_urdf("puma560", _joints, _segments),
    segments=tuple(_segments),
    joint_names=tuple(f"joint{i}" for i in range(1, 7)),
    qlim=QLIM.copy(),
    flange="flange",
    named_poses={k: v.copy() for k, v in NAMED_POSES.items()},
    home_pose="qn",
    start_pose="qz",
    vmax=PUMA_VMAX.copy(),
    amax=PUMA_AMAX.copy(),
    stop_decel=PUMA_STOP_DECEL.copy(),
    default_tool_length=0.1,
    make_kinematics=_kinematics,
)
np.asarray(MODEL.qlim).setflags(write=False)
