"""``--robot.type=telerobot``: a Telerobot server's arm as a LeRobot robot (docs/lerobot.md)."""

from lerobot_robot_telerobot.config_telerobot import TelerobotConfig
from lerobot_robot_telerobot.telerobot import Telerobot

__all__ = ["Telerobot", "TelerobotConfig"]
