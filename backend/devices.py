"""Builds the devices the settings name, through the driver registry."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from backend.settings import Settings
from drivers.base import ArmSnapshot, ForceSensor, Robot, RobotMoved, SerialSettings
from drivers.clock import Clock
from drivers.registry import load_driver
from drivers.robot.puma560.kinematics import NAMED_POSES, Puma560Kinematics, tool_transform
from drivers.sim.workcell import Workcell, default_workcell


def make_kinematics(settings: Settings) -> Puma560Kinematics:
    """The arm's model with the configured tool: the one place it is made (each user
    gets its own: Pinocchio's data is per instance, not thread-safe)."""
    return Puma560Kinematics(tool_transform(settings.tool_length))


def build_workcell(settings: Settings) -> Workcell:
    cell = default_workcell(
        camera_distance=settings.camera_distance,
        baseline=settings.camera_baseline,
        width=settings.video_width,  # the cameras' ground truth is for the video's size
        height=settings.video_height,
    )
    if settings.fiducials is not None:  # where they really are (a real workcell)
        cell = dataclasses.replace(cell, fiducials=np.array(settings.fiducials, dtype=float))
    return cell


def build_robot(settings: Settings, clock: Clock | None = None) -> Robot:
    cls = load_driver("robot", settings.robot)
    common: dict[str, Any] = {
        "kinematics": make_kinematics(settings),
        "clock": clock,
        "home": NAMED_POSES[settings.home_pose],
    }
    # Driver-specific options; the drivers themselves never branch on which one they are.
    specific: dict[str, dict[str, Any]] = {
        "val": {
            "settings": SerialSettings(
                port=settings.serial_port,
                baudrate=settings.serial_baudrate,
                reply_timeout=settings.serial_reply_timeout,
            )
        },
    }
    robot: Robot = cls(**common, **specific.get(settings.robot, {}))
    return robot


def arm_probe(robot: Robot) -> Callable[[], ArmSnapshot]:
    """A thread-safe view of the arm for sensors that simulate contact with it.

    A simulated arm publishes snapshots with velocities; any other arm is followed
    through its "moved" events (position only)."""
    snapshot = getattr(robot, "snapshot", None)
    if callable(snapshot):
        return snapshot  # type: ignore[no-any-return]
    latest = [ArmSnapshot(0.0, robot.joints, np.zeros(6))]

    def on_moved(event: RobotMoved) -> None:
        latest[0] = ArmSnapshot(event.time, event.joints, np.zeros(6))

    robot.events.moved.subscribe(on_moved)
    return lambda: latest[0]


def build_force_sensor(settings: Settings, robot: Robot, workcell: Workcell) -> ForceSensor:
    cls = load_driver("force", settings.force)
    if settings.force == "netft":
        real: ForceSensor = cls(
            settings.netft_address,
            counts_per_force=settings.netft_counts_per_force,
            counts_per_torque=settings.netft_counts_per_torque,
            rate_hz=settings.force_rate_hz,
        )
        return real
    sensor: ForceSensor = cls(
        workcell, arm_probe(robot), make_kinematics(settings), rate_hz=settings.force_rate_hz
    )
    return sensor
