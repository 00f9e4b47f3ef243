"""Builds the devices the settings name, through the driver registry.

The server never asks which driver it holds: each driver class reads its own keys
from the settings in its ``from_settings`` and takes the rest from a ``DeviceContext``
made here (docs/architecture.md, rule 14).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from telerobot.drivers.base import ArmSnapshot, DeviceContext, ForceSensor, Robot, StereoCamera
from telerobot.drivers.clock import Clock
from telerobot.drivers.registry import load_driver
from telerobot.drivers.robot.kinematics import ArmKinematics, tool_transform
from telerobot.drivers.sim.workcell import Workcell, default_workcell
from telerobot.server.settings import Settings


def make_kinematics(settings: Settings) -> ArmKinematics:
    """The arm's kinematics with the configured tool: the one place it is made (each
    user gets its own: Pinocchio's data is per instance, not thread-safe)."""
    return settings.model.kinematics(tool_transform(settings.tool_length_m))


def build_workcell(settings: Settings) -> Workcell:
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
    """What the settings drive, for a person: "the simulation", "the val robot on …"."""
    return load_driver("robot", settings.robot).describe(settings.model_dump())


def build_force_sensor(settings: Settings, robot: Robot, workcell: Workcell) -> ForceSensor:
    """The sensor the settings name; a simulated one feels ``robot`` in ``workcell``."""
    cls = load_driver("force", settings.force)
    context = device_context(settings, workcell=workcell, arm_probe=robot.snapshot)
    return cls.from_settings(settings.model_dump(), context)


def build_camera(settings: Settings, arm_probe: Callable[[], ArmSnapshot]) -> StereoCamera:
    """The stereo camera the settings name (in the media worker, which follows the arm
    through ``arm_probe``)."""
    cls = load_driver("camera", settings.camera)
    context = device_context(settings, arm_probe=arm_probe)
    return cls.from_settings(settings.model_dump(), context)
