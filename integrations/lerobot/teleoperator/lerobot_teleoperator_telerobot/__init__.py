"""``--teleop.type=telerobot``: the operator at a Telerobot server as a LeRobot
teleoperator (docs/lerobot.md)."""

from lerobot_teleoperator_telerobot.config_telerobot import TelerobotTeleopConfig
from lerobot_teleoperator_telerobot.telerobot_teleop import TelerobotTeleop

__all__ = ["TelerobotTeleop", "TelerobotTeleopConfig"]
