"""The motion mark (drivers/camera/motion_mark.py): the tool's position drawn as rulers
beside the timecode, read back from the picture (also through a video codec's loss and
at the low layer's half size), and moving in the simulated camera's frames exactly when
the drawn arm does."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from telerobot.drivers.base import ArmSnapshot
from telerobot.drivers.camera import motion_mark, timecode
from telerobot.drivers.camera.sim import SimStereoCamera
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import default_workcell
from tests.support.video import SMALL


def picture() -> np.ndarray:
    return np.full((360, 640, 3), 150, np.uint8)


@pytest.mark.parametrize("position", [[0.0, 0.0, 0.0], [0.0031, -0.0502, 1.2345], [-1.0, 2.0, 3.0]])
def test_the_rulers_read_back_as_drawn(position: list[float]) -> None:
    img = picture()
    assert motion_mark.draw(img, np.array(position))
    assert motion_mark.read(img) == pytest.approx(motion_mark.lengths(np.array(position)))


def test_the_mark_survives_compression_and_the_half_size_layer() -> None:
    a, b = np.array([0.1, 0.2, 1.2]), np.array([0.1005, 0.2, 1.2])  # 0.5 mm along x
    for pos in (a, b):
        img = picture()
        motion_mark.draw(img, pos)
        timecode.draw(img, 12.5)
        ok, jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 40])
        assert ok
        lossy = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)
        half = cv2.resize(lossy, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        want = motion_mark.lengths(pos)
        assert motion_mark.read(lossy) == pytest.approx(want, abs=1)
        assert motion_mark.read(half, scale=0.5) == pytest.approx(want, abs=2)
        assert timecode.read(lossy) == timecode.encode_time(12.5)  # the mark leaves it be


def test_a_move_is_measured_across_the_wrap() -> None:
    assert motion_mark.moved_px([95.0, 10.0, 3.0], [1.0, 10.0, 3.0]) == 2.0
    assert motion_mark.moved_px([5.0, 10.0, 3.0], [5.0, 7.0, 3.0]) == 3.0
    assert motion_mark.moved_px([5.0, 10.0, 3.0], [5.0, 10.0, 3.0]) == 0.0


def test_an_eye_too_narrow_carries_no_mark() -> None:
    img = np.zeros((360, 600, 3), np.uint8)
    assert not motion_mark.draw(img, np.zeros(3))
    assert motion_mark.read(img) is None


def test_the_sim_camera_draws_the_mark_where_it_draws_the_tool() -> None:
    snap = [ArmSnapshot(10.0, NAMED_POSES["qn"], np.zeros(6))]
    cam = SimStereoCamera(
        default_workcell(**SMALL),
        lambda: snap[0],
        Puma560Kinematics(tool_transform(0.1)),
        time_source=lambda: 10.0,
    )
    still = cam.render(10.0)
    left = still[:, : cam.width]
    at_rest = motion_mark.read(left)
    assert at_rest == pytest.approx(motion_mark.lengths(cam.tool_in_left_camera(NAMED_POSES["qn"])))
    assert timecode.read(left) == timecode.encode_time(10.0)
    # The same joints: the same mark. Joints moving: the mark moves as the arm is drawn
    # (extrapolated to the exposure's time from the newest sample).
    assert motion_mark.read(cam.render(10.5)[:, : cam.width]) == at_rest
    q = NAMED_POSES["qn"] + np.array([0.002, 0, 0, 0, 0, 0])
    snap[0] = ArmSnapshot(10.0, q, np.zeros(6))
    moved = motion_mark.read(cam.render(10.0)[:, : cam.width])
    assert moved is not None and motion_mark.moved_px(at_rest, moved) >= 3
    # Off: the rows are the scene's (no ruler, no black frame).
    plain = SimStereoCamera(
        default_workcell(**SMALL),
        lambda: snap[0],
        Puma560Kinematics(tool_transform(0.1)),
        show_motion_mark=False,
    ).render(10.0)
    assert plain[motion_mark.READ_ROWS[0], motion_mark.X0 : motion_mark.X0 + 8].min() > 0
