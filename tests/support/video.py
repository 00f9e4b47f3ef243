"""Small simulated stereo cameras and encoded frames for the video tests."""

from __future__ import annotations

import asyncio
import time
from typing import TYPE_CHECKING

import numpy as np

from telerobot.drivers.base import ArmSnapshot
from telerobot.drivers.camera import timecode
from telerobot.drivers.camera.sim import SimStereoCamera
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.media.encoder import EncodedFrame

if TYPE_CHECKING:
    from aiortc import RTCPeerConnection

    from telerobot.server.media.pipeline import VideoPipeline

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


async def viewer_of(
    pipeline: VideoPipeline, layer: str = "auto", operator: bool = False
) -> tuple[RTCPeerConnection, object, str]:
    """A real aiortc viewer of ``pipeline`` (in this process) on ``layer``: its peer
    connection, its track once it plays, and its peer id."""
    from aiortc import RTCPeerConnection, RTCSessionDescription

    pc = RTCPeerConnection()
    pc.addTransceiver("video", direction="recvonly")
    got: asyncio.Queue[object] = asyncio.Queue()
    pc.on("track", got.put_nowait)
    await pc.setLocalDescription(await pc.createOffer())
    answer = await pipeline.answer(pc.localDescription.sdp, "offer", layer, operator)  # type: ignore[arg-type]
    await pc.setRemoteDescription(RTCSessionDescription(answer["sdp"], answer["type"]))
    return pc, await asyncio.wait_for(got.get(), 10), answer["peer_id"]


async def frames_of(track: object, n: int, full_width: int) -> list[tuple[int, int, float]]:
    """(eye width, height, capture→decoded s) of the next ``n`` frames of ``track``."""
    out = []
    for _ in range(n):
        f = await asyncio.wait_for(track.recv(), 10)  # type: ignore[attr-defined]
        rgb = f.to_ndarray(format="rgb24")
        eye = rgb[:, : rgb.shape[1] // 2]
        code = timecode.read(eye, scale=eye.shape[1] / full_width)
        assert code is not None, f"no timecode in a {eye.shape[1]}×{eye.shape[0]} picture"
        out.append((eye.shape[1], eye.shape[0], timecode.elapsed(code, time.monotonic())))
    return out
