"""Builds the devices the settings name, through the driver registry.

The server never asks which driver it holds: each driver class reads its own keys
from the settings in its ``from_settings`` and takes the rest from a ``DeviceContext``
made here (docs/architecture.md, rule 14).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from telerobot.drivers.base import (
    ArmSnapshot,
    DeviceContext,
    FloatArray,
    ForceSensor,
    Robot,
    StereoCamera,
)
from telerobot.drivers.clock import Clock
from telerobot.drivers.registry import load_driver
from telerobot.drivers.robot.kinematics import ArmKinematics, tool_transform
from telerobot.drivers.sim.workcell import (
    Workcell,
    default_workcell,
    facing_mounts,
    mount_transform,
)
from telerobot.server.settings import Settings


def make_kinematics(settings: Settings) -> ArmKinematics:
    """The arm's kinematics with the configured tool: the one place it is made (each
    user gets its own: Pinocchio's data is per instance, not thread-safe)."""
    return settings.model.kinematics(tool_transform(settings.tool_length_m))


@dataclass(frozen=True)
class ArmDevices:
    """One arm the server drives: its name, its settings (the server's with its own
    over them), its driver and force sensor, and where its base stands (4×4, in the
    workcell's frame)."""

    name: str
    settings: Settings
    robot: Robot
    force: ForceSensor
    mount: FloatArray


def arm_mounts(settings: Settings) -> list[FloatArray]:
    """Each arm's base in the workcell (in the settings' arm order): its ``mount`` if
    set; else the first at the origin and, of two, the second across the table facing
    it (``facing_mounts``). A third arm or more needs its mount said."""
    arms = settings.arm_settings()
    model = arms[0][1].model
    facing = facing_mounts(model.scene_scale, model.scene_offset)
    mounts = []
    for i, (name, own) in enumerate(arms):
        if own.mount is not None:
            mounts.append(mount_transform(own.mount))
        elif i < 2:
            mounts.append(facing[i])
        else:
            raise ValueError(
                f"arms.{name}: say where its base stands (mount = [x, y, z, turn°]): the"
                " simulated workcell places two arms by itself, not three"
            )
    return mounts


def build_workcell(settings: Settings) -> Workcell:
    mounts = arm_mounts(settings) if settings.arms else []
    settings = settings.arm_settings()[0][1]  # the scene is sized for the first arm's model
    cell = default_workcell(
        camera_distance=settings.camera_distance,
        baseline=settings.camera_baseline,
        width=settings.video_width,  # the cameras' ground truth is for the video's size
        height=settings.video_height,
        block_stiffness=settings.block_stiffness_n_m,
        block_damping=settings.block_damping_n_s_m,
        scale=settings.model.scene_scale,
        offset=settings.model.scene_offset,
        pedestal_m=settings.model.pedestal_m,
        mounts=tuple(mounts),
    )
    if settings.fiducials is not None:  # where they really are (a real workcell)
        cell = dataclasses.replace(cell, fiducials=np.array(settings.fiducials, dtype=float))
    return cell


def device_context(
    settings: Settings,
    *,
    clock: Clock | None = None,
    workcell: Workcell | None = None,
    arm_probe: Callable[[], ArmSnapshot] | None = None,
) -> DeviceContext:
    """What the server gives every driver besides the settings: the kinematics factory,
    the workcell (this one, else built on first need), the arm to follow, the clock."""

    def the_workcell() -> Workcell:
        return workcell if workcell is not None else build_workcell(settings)

    context = DeviceContext(
        kinematics=lambda: make_kinematics(settings), workcell=the_workcell, clock=clock
    )
    return context if arm_probe is None else dataclasses.replace(context, arm_probe=arm_probe)


def build_robot(settings: Settings, clock: Clock | None = None) -> Robot:
    cls = load_driver("robot", settings.robot)
    return cls.from_settings(settings.model_dump(), device_context(settings, clock=clock))


def describe_robot(settings: Settings) -> str:
    """What the settings drive, for a person: "the simulation", "the val robot on …";
    with two arms or more, each by name ("left: the simulation, right: …")."""
    if not settings.arms:
        return load_driver("robot", settings.robot).describe(settings.model_dump())
    return ", ".join(
        f"{name}: {load_driver('robot', own.robot).describe(own.model_dump())}"
        for name, own in settings.arm_settings()
    )


def build_force_sensor(
    settings: Settings,
    robot: Robot,
    workcell: Workcell,
    mount: FloatArray | None = None,
    phase: float = 0.0,
) -> ForceSensor:
    """The sensor the settings name; a simulated one feels ``robot`` in ``workcell``
    (seen from the arm's base at ``mount``: its sensor's physics is in the arm's frame),
    sampling at ``phase`` of its period (arm i of N: i/N)."""
    cls = load_driver("force", settings.force)
    cell = workcell if mount is None else workcell.seen_from(mount)
    context = dataclasses.replace(
        device_context(settings, workcell=cell, arm_probe=robot.snapshot), sample_phase=phase
    )
    return cls.from_settings(settings.model_dump(), context)


def build_arms(settings: Settings, clock: Clock | None, workcell: Workcell) -> list[ArmDevices]:
    """Every arm the settings name, each with its own driver and force sensor (one arm,
    named "arm", when they name none)."""
    mounts = arm_mounts(settings)
    arms = []
    named = settings.arm_settings()
    for i, ((name, own), mount) in enumerate(zip(named, mounts, strict=True)):
        robot = build_robot(own, clock)
        sensor = build_force_sensor(own, robot, workcell, mount, phase=i / len(named))
        arms.append(ArmDevices(name, own, robot, sensor, mount))
    return arms


def build_camera(settings: Settings, arm_probe: Callable[[], ArmSnapshot]) -> StereoCamera:
    """The stereo camera the settings name (in the media worker, which follows the arm
    through ``arm_probe``)."""
    cls = load_driver("camera", settings.camera)
    context = device_context(settings, arm_probe=arm_probe)
    return cls.from_settings(settings.model_dump(), context)
