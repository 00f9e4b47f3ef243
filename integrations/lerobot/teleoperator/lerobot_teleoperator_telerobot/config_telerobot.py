"""The teleoperator's settings, as ``--teleop.<field>=…`` on LeRobot's command lines."""

from dataclasses import dataclass, field

from lerobot.teleoperators.config import TeleoperatorConfig

from telerobot.client import local_url, stored_token


@TeleoperatorConfig.register_subclass("telerobot")
@dataclass
class TelerobotTeleopConfig(TeleoperatorConfig):
    # The server, and a token to read it with (as the robot's: TELEROBOT_URL and
    # TELEROBOT_OPERATOR_TOKEN, else this machine's server's).
    url: str = field(default_factory=local_url)
    token: str = field(default_factory=lambda: stored_token() or "")
    # The Telerobot robot's client_name: its own control is no operator's intervention.
    robot_client_name: str = "lerobot"
