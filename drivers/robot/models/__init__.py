"""Robot descriptions: what an arm is, apart from how it is driven.

A ``RobotModel`` is a URDF (written here from data, or generated from a DH table as
for the PUMA 560), its joints' names and limits, the link the tool is mounted on, named
poses, the drives' speed limits, and how to make its kinematics with a tool: closed
form where the arm has one (the PUMA), numeric from the URDF otherwise. A driver moves
"an arm of this model"; the server, the simulation and the page read the model.

Models are found by name, imported only when chosen (as drivers are): ``load_model``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Final

import numpy as np

from telerobot.drivers.base import DriverUnavailable, FloatArray
from telerobot.drivers.robot.models.urdf import Segment

if TYPE_CHECKING:
    from telerobot.drivers.robot.kinematics import ArmKinematics
    from telerobot.drivers.robot.models.numeric import Chain

# name → the module holding its MODEL
MODELS: Final[dict[str, str]] = {
    "puma560": "telerobot.drivers.robot.models.puma560",
    "so101": "telerobot.drivers.robot.models.so101",
}
DEFAULT_MODEL: Final = "puma560"


@dataclass(frozen=True)
class RobotModel:
    name: str  # as the settings say it: "puma560", "so101"
    title: str  # for a person: "PUMA 560"
    urdf: str  # the description, URDF text
    joint_names: tuple[str, ...]
    qlim: FloatArray  # (n, 2) lower, upper, radians
    flange: str  # the URDF link the tool is mounted on
    named_poses: Mapping[str, FloatArray]
    home_pose: str  # the pose ``initialize()`` goes to by default
    start_pose: str  # where a simulated arm is when it is switched on
    vmax: FloatArray  # rad/s per joint
    amax: FloatArray  # rad/s² per joint
    stop_decel: FloatArray  # rad/s² per joint, a controlled stop
    default_tool_length: float  # metres along the flange's z axis
    make_kinematics: Callable[[FloatArray | None], ArmKinematics] = field(repr=False)
    # The simulated workcell (sized for the PUMA) scaled about the base and moved, so
    # the table and block are in this arm's reach; the tool's workspace box likewise.
    scene_scale: float = 1.0
    scene_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    pedestal_m: float = 0.6  # drawn under the base (the PUMA's); 0: on the table
    workspace_min: tuple[float, float, float] = (-0.2, -0.8, 0.30)
    workspace_max: tuple[float, float, float] = (1.05, 0.8, 1.60)
    segments: tuple[Segment, ...] = ()  # the URDF's drawing: cylinders in link frames

    @property
    def dof(self) -> int:
        return len(self.joint_names)

    def kinematics(self, tool: FloatArray | None = None) -> ArmKinematics:
        """A new kinematic model of this arm with ``tool`` (4×4 in the flange frame).
        Each user gets its own: Pinocchio's data is per instance."""
        return self.make_kinematics(tool)

    def pose(self, name: str) -> FloatArray:
        try:
            return self.named_poses[name].copy()
        except KeyError:
            known = ", ".join(sorted(self.named_poses))
            raise DriverUnavailable(
                f"the {self.title} has no pose {name!r} (known: {known})"
            ) from None

    def chain(self) -> Chain:
        """The joint tree as plain numbers, for a client that computes forward
        kinematics itself (the page)."""
        from telerobot.drivers.robot.models.numeric import describe_chain

        return describe_chain(self.urdf, self.flange)

    def describe(self) -> dict[str, object]:
        """The model as JSON (the recording's metadata, the CLI)."""
        return {
            "name": self.name,
            "title": self.title,
            "dof": self.dof,
            "joint_names": list(self.joint_names),
            "joint_limits_rad": np.round(self.qlim, 6).tolist(),
            "flange": self.flange,
            "named_poses": {k: np.round(v, 6).tolist() for k, v in self.named_poses.items()},
            "home_pose": self.home_pose,
            "vmax_rad_s": self.vmax.tolist(),
            "default_tool_length_m": self.default_tool_length,
        }


def model_names() -> list[str]:
    return sorted(MODELS)


_loaded: dict[str, RobotModel] = {}


def load_model(name: str) -> RobotModel:
    """The model called ``name`` (``DriverUnavailable`` naming the known ones if none)."""
    if name not in _loaded:
        try:
            module = importlib.import_module(MODELS[name])
        except KeyError:
            known = ", ".join(model_names())
            raise DriverUnavailable(f"unknown robot model {name!r} (known: {known})") from None
        model: RobotModel = module.MODEL
        _loaded[name] = model
    return _loaded[name]
