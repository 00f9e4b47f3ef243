"""``Annotated`` dependency aliases: devices live on ``app.state``, never in globals."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from backend.settings import Settings
from drivers.base import Robot
from drivers.sim.workcell import Workcell


def get_robot(request: Request) -> Robot:
    robot: Robot = request.app.state.robot
    return robot


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


def get_workcell(request: Request) -> Workcell:
    workcell: Workcell = request.app.state.workcell
    return workcell


RobotDep = Annotated[Robot, Depends(get_robot)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
WorkcellDep = Annotated[Workcell, Depends(get_workcell)]
