"""Two arms in the simulation (docs/arms.md, issue 33): the simulated stereo camera
draws every arm from its own model at its mount, as the media worker builds it from the
settings; moving one arm changes only its pixels; one arm is drawn as it always was;
each arm reaches the block at the table's middle from its own side and only the arm
pressing it feels it; the media worker process draws every arm from the state the
server shares; the 3D view places each arm at its mount."""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import cast

import av
import cv2
import numpy as np
import pytest

from telerobot.calibration.store import CalibrationStore
from telerobot.drivers.base import ArmSnapshot, FloatArray
from telerobot.drivers.camera.sim import GRIPPER_COLOUR, SimStereoCamera
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.robot.models.drawing import ArmDrawing
from telerobot.drivers.sim.workcell import PinholeCamera
from telerobot.server.devices import (
    arm_mounts,
    build_arms,
    build_robot,
    build_workcell,
    make_kinematics,
)
from telerobot.server.media.supervisor import MediaSupervisor
from telerobot.server.media.worker import build_arms_camera
from telerobot.server.recording.video import VideoTap
from telerobot.server.settings import Settings
from telerobot.server.viewer3d import ViewedArm, Workcell3DView
from tests.support.clock import run_with_clock

W, H = 640, 360  # each eye: fast enough for tests


def pair(model: str) -> Settings:
    """Two simulated arms of ``model``, left and right, across the table."""
    return Settings(arms=f"left={model}:sim,right={model}:sim", video_width=W, video_height=H)


class Arms:
    """Each arm's state as the camera reads it; the test sets the joints."""

    def __init__(self, settings: Settings, poses: list[str]) -> None:
        self.settings = [own for _, own in settings.arm_settings()]
        self.mounts = arm_mounts(settings)
        self.q = [own.model.pose(p) for own, p in zip(self.settings, poses, strict=True)]

    def probe(self, i: int) -> Callable[[], ArmSnapshot]:
        return lambda: ArmSnapshot(0.0, self.q[i], np.zeros(len(self.q[i])))

    def tool(self, i: int) -> FloatArray:
        """Where arm ``i``'s tool is in the workcell: its mount @ its fk."""
        fk = make_kinematics(self.settings[i]).fk(self.q[i])
        result: FloatArray = (self.mounts[i] @ fk)[:3, 3]
        return result


def camera_for(settings: Settings, arms: Arms) -> SimStereoCamera:
    camera = build_arms_camera(settings, [arms.probe(i) for i in range(len(arms.q))])
    assert isinstance(camera, SimStereoCamera)
    camera.show_timecode = False
    camera.show_motion_mark = False  # (drawn beside the timecode: both off for a clean frame)
    return camera


def eyes(camera: SimStereoCamera, sbs: np.ndarray) -> list[tuple[PinholeCamera, np.ndarray]]:
    w = camera.width
    return [(cam, sbs[:, i * w : (i + 1) * w]) for i, cam in enumerate(camera.cameras)]


def pixel(img: np.ndarray, uv: FloatArray) -> tuple[int, ...]:
    u, v = np.round(uv).astype(int)
    return tuple(int(c) for c in img[v, u])


def footprint(camera: SimStereoCamera, arms: Arms, i: int) -> np.ndarray:
    """The pixels arm ``i`` covers alone (a one-arm camera at its mount), grown by a pixel
    for the anti-aliased edge."""
    own = arms.settings[i]
    alone = SimStereoCamera(
        dataclasses.replace(camera.workcell, mounts=(arms.mounts[i],)),
        arms.probe(i),
        make_kinematics(own),
        drawing=ArmDrawing(own.model),
        show_timecode=False,
    )
    drawn = np.any(alone.render(0.0) != alone.background, axis=2).astype(np.uint8)
    return cv2.dilate(drawn, np.ones((3, 3), np.uint8)).astype(bool)


@pytest.mark.parametrize(
    ("model", "poses"), [("so101", ["ready", "zero"]), ("puma560", ["qn", "qs"])]
)
def test_each_arm_is_drawn_where_the_cameras_see_its_tool(model: str, poses: list[str]) -> None:
    settings = pair(model)
    arms = Arms(settings, poses)
    camera = camera_for(settings, arms)
    assert len(camera.arms) == 2
    sbs = camera.render(0.0)
    tools = [arms.tool(0), arms.tool(1)]
    assert np.linalg.norm(tools[0] - tools[1]) > 0.05  # two grippers, apart
    for cam, img in eyes(camera, sbs):
        for tool in tools:
            assert cam.in_view(tool[None])[0]
            assert pixel(img, cam.project(tool[None])[0]) == GRIPPER_COLOUR
    # Each arm stands at its own base: the right one drawn in the left one's frame (its
    # mount left out) would put its gripper where no gripper is.
    unmounted = make_kinematics(arms.settings[1]).fk(arms.q[1])[:3, 3]
    cam, img = eyes(camera, sbs)[0]
    assert pixel(img, cam.project(unmounted[None])[0]) != GRIPPER_COLOUR


def test_moving_one_arm_changes_only_its_own_pixels() -> None:
    settings = pair("so101")
    arms = Arms(settings, ["ready", "ready"])
    camera = camera_for(settings, arms)
    before, right_before = camera.render(0.0), footprint(camera, arms, 1)
    left_gripper = [
        pixel(img, cam.project(arms.tool(0)[None])[0]) for cam, img in eyes(camera, before)
    ]
    arms.q[1] = arms.settings[1].model.pose("zero")
    after, right_after = camera.render(0.0), footprint(camera, arms, 1)
    changed = np.any(before != after, axis=2)
    assert changed.sum() > 500  # the right arm moved on screen
    assert not (changed & ~(right_before | right_after)).any()  # and nothing else did
    assert left_gripper == [GRIPPER_COLOUR, GRIPPER_COLOUR]
    for cam, img in eyes(camera, after):
        assert pixel(img, cam.project(arms.tool(0)[None])[0]) == GRIPPER_COLOUR
        assert pixel(img, cam.project(arms.tool(1)[None])[0]) == GRIPPER_COLOUR


def test_one_arm_is_drawn_as_it_always_was() -> None:
    """A one-arm server's camera is the one-arm camera the other tests build; in a
    two-arm frame the first arm is drawn exactly as that camera draws it alone."""
    one = Settings(video_width=W, video_height=H)
    snap = ArmSnapshot(0.0, one.model.pose("qn"), np.zeros(6))
    built = build_arms_camera(one, [lambda: snap])
    assert isinstance(built, SimStereoCamera) and len(built.arms) == 1
    assert np.array_equal(built.arms[0].mount, np.eye(4)) and built.arms[0].pedestal_m == 0.6
    by_hand = SimStereoCamera(
        build_workcell(one), lambda: snap, make_kinematics(one), drawing=ArmDrawing(one.model)
    )
    assert np.array_equal(built.render(1.0), by_hand.render(1.0))

    settings = pair("so101")
    arms = Arms(settings, ["ready", "zero"])
    camera = camera_for(settings, arms)
    both = camera.render(0.0)
    alone = SimStereoCamera(
        camera.workcell,
        arms.probe(0),
        make_kinematics(arms.settings[0]),
        drawing=ArmDrawing(arms.settings[0].model),
        show_timecode=False,
    ).render(0.0)
    right = footprint(camera, arms, 1)
    assert np.array_equal(both[~right], alone[~right])


@pytest.mark.parametrize("model", ["so101", "puma560"])
async def test_each_arm_reaches_the_block_and_only_the_one_pressing_it_feels_it(
    model: str,
) -> None:
    settings = pair(model)
    clock = ManualClock()
    workcell = build_workcell(settings)
    arms = build_arms(settings, clock, workcell)
    pressing: list[FloatArray] = []
    for arm in arms:  # the block's top, from each arm's own side, in its own frame
        own = arm.settings.model
        block = workcell.seen_from(arm.mount).block
        top = block.centre + [0.0, 0.0, block.size[2] / 2]
        assert np.all(top >= own.workspace_min) and np.all(top <= own.workspace_max)
        kinematics = make_kinematics(arm.settings)
        home = own.pose(arm.settings.home_pose_name)
        target = kinematics.fk(home)
        target[:3, 3] = top - [0.0, 0.0, 0.003]  # 3 mm into it
        q = kinematics.ik(target, home)
        assert np.allclose(kinematics.fk(q)[:3, 3], target[:3, 3], atol=1e-4)
        pressing.append(q)
        await arm.robot.connect()
        await run_with_clock(clock, arm.robot.initialize())
    left, right = arms
    await right.robot.move_joints(pressing[1], relative=False)
    await run_with_clock(clock, right.robot.wait_idle())
    sensors = [arm.force for arm in arms]
    assert all(isinstance(sensor, SimForceSensor) for sensor in sensors)
    felt = [np.linalg.norm(cast(SimForceSensor, s).read_raw(clock.now())[:3]) for s in sensors]
    stiffness = workcell.block.stiffness
    assert felt[1] == pytest.approx(stiffness * 0.003, rel=0.05)  # the block pushes back
    assert felt[0] < 0.5  # the left arm, at home, feels only the sensor's noise
    # In the workcell's own frame too, the right arm's tool is 3 mm into the block.
    tool = (right.mount @ make_kinematics(right.settings).fk(right.robot.joints))[:3, 3]
    assert workcell.block.penetration(tool)[0] == pytest.approx(0.003, abs=1e-4)
    assert left.robot.joints == pytest.approx(
        left.settings.model.pose(left.settings.home_pose_name)
    )
    for arm in arms:
        await arm.robot.disconnect()


async def test_the_media_worker_draws_every_arm_from_the_state_the_server_shares(
    tmp_path: Path,
) -> None:
    """The real worker process: two simulated SO-101s in different poses; a frame of
    the video it encodes shows each arm's gripper where the ground-truth cameras see
    its tool."""
    settings = Settings(
        state_dir=tmp_path,
        arms={
            "left": {"robot_model": "so101", "robot": "sim"},
            "right": {"robot_model": "so101", "robot": "sim", "home_pose": "rest"},
        },
        sim_starts_at_home=True,
        video_fps=30,
        keyframe_interval_s=10.0,
        video_width=W,
        video_height=H,
    )
    robots = [build_robot(own) for _, own in settings.arm_settings()]
    with pytest.raises(ValueError, match="follows 2 arms, but was given 1"):
        MediaSupervisor(settings, robots[0])
    media = MediaSupervisor(settings, robots)
    packets: list[bytes] = []
    tap = VideoTap(media)
    await media.start()
    try:
        await tap.start(lambda _topic, payload: packets.append(payload["data"]))
        deadline = time.monotonic() + 60
        while len(packets) < 5:
            assert time.monotonic() < deadline, f"only {len(packets)} packets"
            await asyncio.sleep(0.1)
        await tap.stop()
    finally:
        await media.stop()
    ctx = av.CodecContext.create("h264", "r")
    frames = [f for p in packets for f in ctx.decode(av.Packet(p))]
    sbs = frames[-1].to_ndarray(format="rgb24")
    arms = Arms(settings, ["ready", "rest"])  # not zeros: an arm never published is at 0
    expected = camera_for(settings, arms)
    assert sbs.shape == (H, 2 * W, 3)
    for cam, img in eyes(expected, sbs):
        for i in range(2):
            r, g, b = pixel(img, cam.project(arms.tool(i)[None])[0])
            assert r > 200 and 90 < g < 190 and b < 80, (i, (r, g, b))  # orange, as encoded


async def test_the_3d_view_draws_every_arm_at_its_mount(tmp_path: Path) -> None:
    settings = pair("so101")
    workcell = build_workcell(settings)
    arms = build_arms(settings, None, workcell)
    view = Workcell3DView(
        "127.0.0.1",
        0,
        workcell,
        [ViewedArm(a.robot, make_kinematics(a.settings), a.mount, a.force) for a in arms],
        CalibrationStore(tmp_path / "calibration.json"),
    )
    try:
        view.refresh()
        for arm, nodes in zip(arms, view.nodes, strict=True):
            fk = make_kinematics(arm.settings).fk(arm.robot.joints)
            tool = (arm.mount @ fk)[:3, 3]
            assert np.allclose(nodes.gripper.position, tool)
            assert np.allclose(nodes.links.points[0, 0], arm.mount[:3, 3])  # from its base
        assert not np.allclose(view.nodes[0].gripper.position, view.nodes[1].gripper.position)
    finally:
        await view.stop()
