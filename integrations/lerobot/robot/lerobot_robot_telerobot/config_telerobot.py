"""The robot's settings, as ``--robot.<field>=…`` on LeRobot's command lines."""

import os
from dataclasses import dataclass, field

from lerobot.robots.config import RobotConfig
from pydantic import SecretStr

from telerobot.client import local_url, stored_token
from telerobot.client.lerobot.draccus_tokens import given_or, teach_draccus

teach_draccus()  # the tokens are SecretStr: --robot.token=… read into one


def _policy_token() -> str | None:
    return os.environ.get("TELEROBOT_POLICY_TOKEN")


@RobotConfig.register_subclass("telerobot")
@dataclass
class TelerobotConfig(RobotConfig):
    # The server: TELEROBOT_URL, else http://localhost:8000 (what `make run` serves).
    url: str = field(default_factory=local_url)
    # The operator token: TELEROBOT_OPERATOR_TOKEN, else the one `telerobot serve` keeps
    # on this machine. Commands need it; without it the server refuses control. Held as
    # a SecretStr: no repr, log line or error shows it (a str given is made one).
    token: SecretStr = field(default_factory=lambda: given_or(None, stored_token))
    # The name this robot's client holds control by (the page shows it; the Telerobot
    # teleoperator tells an operator's control from it).
    client_name: str = "lerobot"
    # The server's stereo pair as the cameras `left` and `right`, each frame resized to
    # camera_width × camera_height (one eye); False: joints and force only.
    use_cameras: bool = True
    camera_width: int = 640
    camera_height: int = 480
    fps: float = 30.0  # the rate get_observation waits for a new frame at
    # Each joint approaches its target at most this fast (the server's limits still apply).
    max_speed_rad_s: float = 0.95
    # Take control from whoever holds it (else connecting fails while someone drives).
    take_over: bool = False
    # A learned policy drives this robot (lerobot-rollout): the server supervises it, an
    # operator at the page takes over at will and hands back (docs/lerobot.md). It starts
    # paused: a person lets it drive (P on the page, POST /api/v1/autonomy/resume).
    policy: bool = False
    # The credential a policy joins with (TELEROBOT_POLICY_TOKEN): a policy token, which
    # can only drive, and only while a person lets it. An operator issues it with
    # `telerobot policy-token new NAME`; the operator token is refused for a policy.
    policy_token: SecretStr = field(default_factory=lambda: given_or(None, _policy_token))

    def __post_init__(self) -> None:
        super().__post_init__()
        self.token = given_or(self.token, stored_token)
        self.policy_token = given_or(self.policy_token, _policy_token)
