"""``TelerobotTeleop``: LeRobot's ``Teleoperator`` over
``telerobot.client.lerobot.operator.TelerobotOperator``: the operator's joint targets
as the action, their holding control as ``IS_INTERVENTION``. On a two-arm server, the
robot plugin's shape: each arm's keys prefixed with its name (two SO-101s named left
and right: LeRobot's ``bi_so_leader``, left first)."""

from __future__ import annotations

from functools import cached_property
from typing import Any

from lerobot.teleoperators.teleoperator import Teleoperator
from lerobot.teleoperators.utils import TeleopEvents
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from lerobot_teleoperator_telerobot.config_telerobot import TelerobotTeleopConfig
from telerobot.client.lerobot.operator import OperatorOptions, TelerobotOperator
from telerobot.client.lerobot.parts import describe_arms


class TelerobotTeleop(Teleoperator):
    config_class = TelerobotTeleopConfig
    name = "telerobot"

    def __init__(self, config: TelerobotTeleopConfig) -> None:
        super().__init__(config)
        self.config = config
        # LeRobot asks for the features before it connects: the arms' joints are the
        # server's, asked now.
        self.keys = [k for p in describe_arms(config.url) for k in p.keys]
        self.operator = TelerobotOperator(
            OperatorOptions(config.url, config.token, config.robot_client_name)
        )

    @cached_property
    def action_features(self) -> dict[str, type]:
        return {k: float for k in self.keys}

    @cached_property
    def feedback_features(self) -> dict[str, type]:
        return {}  # the server streams the forces to the operator itself

    @property
    def is_connected(self) -> bool:
        return self.operator.connected

    def connect(self, calibrate: bool = True) -> None:
        if self.operator.connected:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        self.operator.connect()

    @property
    def is_calibrated(self) -> bool:
        return True

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def get_action(self) -> dict[str, float]:
        if not self.operator.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        return self.operator.action()

    def get_teleop_events(self) -> dict[Any, Any]:
        if not self.operator.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        return {
            TeleopEvents.IS_INTERVENTION: self.operator.intervening(),
            TeleopEvents.TERMINATE_EPISODE: False,
            TeleopEvents.SUCCESS: False,
            TeleopEvents.RERECORD_EPISODE: False,
        }

    def send_feedback(self, feedback: dict[str, Any]) -> None:
        pass  # forces reach the operator's page and master arm from the server, at 1 kHz

    def disconnect(self) -> None:
        if not self.operator.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        self.operator.disconnect()
