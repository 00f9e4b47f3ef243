"""Builds the devices the settings name, through the driver registry."""

from __future__ import annotations

from typing import Any

from backend.settings import Settings
from drivers.base import Robot, SerialSettings
from drivers.clock import Clock
from drivers.registry import load_driver
from drivers.robot.puma560.kinematics import NAMED_POSES, Puma560Kinematics, tool_transform
from drivers.sim.workcell import Workcell, default_workcell


def build_workcell(settings: Settings) -> Workcell:
    return default_workcell(
        camera_distance=settings.camera_distance, baseline=settings.camera_baseline
    )


def build_robot(settings: Settings, clock: Clock | None = None) -> Robot:
    cls = load_driver("robot", settings.robot)
    common: dict[str, Any] = {
        "kinematics": Puma560Kinematics(tool_transform(settings.tool_length)),
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
