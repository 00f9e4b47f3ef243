"""The simulated PUMA 560 is the generic simulated arm with the PUMA's model."""

from telerobot.drivers.robot.sim import SimPuma

__all__ = ["SimPuma"]
