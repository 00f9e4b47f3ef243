"""Emulated SO-101 servo buses for tests that run the real driver: a follower's and a
leader's calibration (each arm assembled its own way: their zeros differ) and a bus
emulator whose servos start at a pose."""

from __future__ import annotations

from telerobot.drivers.base import FloatArray
from telerobot.drivers.robot.models import load_model
from telerobot.drivers.robot.so101.calibration import JointCalibration, So101Calibration
from telerobot.drivers.robot.so101.emulator import FeetechBusEmulator

SO101 = load_model("so101")


def calibration(zeros: list[tuple[float, int]]) -> So101Calibration:
    return So101Calibration(
        SO101.joint_names,
        tuple(JointCalibration(i + 1, zero, d) for i, (zero, d) in enumerate(zeros)),
    )


FOLLOWER_CAL = calibration(
    [(2048.0, 1), (2100.0, -1), (1990.0, 1), (2050.0, 1), (2048.0, -1), (1900.0, 1)]
)
LEADER_CAL = calibration(
    [(2000.0, -1), (2048.0, 1), (2150.0, 1), (1980.0, -1), (2048.0, 1), (2200.0, -1)]
)


def emulated(cal: So101Calibration, pose: FloatArray) -> FeetechBusEmulator:
    """A bus whose servos stand where ``cal`` puts ``pose``."""
    steps = dict(zip(cal.ids, map(float, cal.to_steps(pose)), strict=True))
    return FeetechBusEmulator(start=steps)
