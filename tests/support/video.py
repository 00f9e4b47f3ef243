"""Small simulated stereo cameras and encoded frames for the video tests."""

from __future__ import annotations

import time

import numpy as np

from telerobot.drivers.base import ArmSnapshot
from telerobot.drivers.camera.sim import SimStereoCamera
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.media.encoder import EncodedFrame

SMALL = dict(width=640, height=360)  # fast enough for tests; the benchmark runs 1280×720


def camera(fps: float = 30.0, **cell: int) -> SimStereoCamera:
    snap = ArmSnapshot(time.monotonic(), NAMED_POSES["qn"], np.zeros(6))
    return SimStereoCamera(
        default_workcell(**cell), lambda: snap, Puma560Kinematics(tool_transform(0.1)), fps=fps
    )


def frame(keyframe: bool, seq: int = 0) -> EncodedFrame:
    return EncodedFrame(packet=None, keyframe=keyframe, size=100, capture_time=0.0, seq=seq,
                        encode_ms=1.0)  # fmt: skip


class Counter:
    def __init__(self) -> None:
        self.n = 0

    def __call__(self) -> None:
        self.n += 1
