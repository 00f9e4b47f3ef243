"""``Telerobot``: LeRobot's ``Robot`` over ``telerobot.client.lerobot.arm.TelerobotArm``:
a server's one arm as LeRobot's robot of that arm, its two arms as LeRobot's bimanual
robot of them (``bi_so_follower`` for two SO-101s named left and right).

Everything the arm does is the server's: the limits, the lease, the dead-man and the
e-stop apply to every target sent; ``send_action`` returns the target as applied
(clipped to the limits), or, while someone else holds control, the server's target
(their commands are applied by the server, not sent again).
"""

from __future__ import annotations

from functools import cached_property
from typing import Any

from lerobot.robots.robot import Robot
from lerobot.utils.errors import DeviceAlreadyConnectedError, DeviceNotConnectedError

from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
from telerobot.client.lerobot.arm import (
    ArmOptions,
    TelerobotArm,
    describe_arms,
    observation_features,
    robot_type,
)


class Telerobot(Robot):
    config_class = TelerobotConfig
    name = "telerobot"

    def __init__(self, config: TelerobotConfig) -> None:
        super().__init__(config)
        self.config = config
        if config.policy and not config.policy_token.get_secret_value():
            raise ValueError(
                "a policy joins with a policy token: --robot.policy_token=… or"
                " TELEROBOT_POLICY_TOKEN (an operator issues one: telerobot policy-token new"
                " NAME); the operator token is refused for a policy"
            )
        self.options = ArmOptions(
            url=config.url,
            token=config.policy_token if config.policy else config.token,
            name=config.client_name,
            cameras=config.use_cameras,
            width=config.camera_width,
            height=config.camera_height,
            fps=config.fps,
            max_speed_rad_s=config.max_speed_rad_s,
            take_over=config.take_over,
            policy=config.policy,
        )
        # LeRobot asks for the features before it connects: the arms' joints are the
        # server's, asked now. A dataset is named for the arms (an SO-101's is LeRobot's
        # so_follower, two SO-101s named left and right its bi_so_follower), not for the
        # way to them.
        parts = describe_arms(config.url)
        self.keys = [k for p in parts for k in p.keys]
        self.name = self.robot_type = robot_type(parts)
        self.arm = TelerobotArm(self.options)
        # lerobot-record sizes its image writers by the cameras it sees here.
        self.cameras: dict[str, Any] = {"left": None, "right": None} if config.use_cameras else {}

    @cached_property
    def observation_features(self) -> dict[str, Any]:
        return observation_features(self.keys, self.options)

    @cached_property
    def action_features(self) -> dict[str, type]:
        return {k: float for k in self.keys}

    @property
    def is_connected(self) -> bool:
        return self.arm.connected

    def connect(self, calibrate: bool = True) -> None:
        if self.arm.connected:
            raise DeviceAlreadyConnectedError(f"{self} is already connected")
        self.arm.connect()

    @property
    def is_calibrated(self) -> bool:
        return True  # the server's arm is calibrated on the server

    def calibrate(self) -> None:
        pass

    def configure(self) -> None:
        pass

    def get_observation(self) -> dict[str, Any]:
        if not self.arm.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        return self.arm.observation()

    def send_action(self, action: dict[str, Any]) -> dict[str, Any]:
        if not self.arm.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        return self.arm.send(action)

    def disconnect(self) -> None:
        if not self.arm.connected:
            raise DeviceNotConnectedError(f"{self} is not connected")
        self.arm.disconnect()
