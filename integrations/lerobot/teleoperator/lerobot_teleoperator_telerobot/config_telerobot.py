"""The teleoperator's settings, as ``--teleop.<field>=…`` on LeRobot's command lines."""

from dataclasses import dataclass, field

from lerobot.teleoperators.config import TeleoperatorConfig
from pydantic import SecretStr

from telerobot.client import local_url, stored_token
from telerobot.client.lerobot.draccus_tokens import given_or, teach_draccus

teach_draccus()  # the token is a SecretStr: --teleop.token=… read into one


@TeleoperatorConfig.register_subclass("telerobot")
@dataclass
class TelerobotTeleopConfig(TeleoperatorConfig):
    # The server, and a token to read it with (as the robot's: TELEROBOT_URL and
    # TELEROBOT_OPERATOR_TOKEN, else this machine's server's). Held as a SecretStr: no
    # repr, log line or error shows it (a str given is made one).
    url: str = field(default_factory=local_url)
    token: SecretStr = field(default_factory=lambda: given_or(None, stored_token))
    # The Telerobot robot's client_name: its own control is no operator's intervention.
    robot_client_name: str = "lerobot"

    def __post_init__(self) -> None:
        self.token = given_or(self.token, stored_token)
