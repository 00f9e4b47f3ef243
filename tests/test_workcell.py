from __future__ import annotations

import numpy as np
import pytest

from telerobot.drivers.base import InvalidCommand
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.sim.workcell import PinholeCamera, default_workcell, stereo_rig


def test_cameras_see_the_work_area_fiducials_and_block() -> None:
    cell = default_workcell()
    for cam in (cell.rig.left, cell.rig.right):
        assert cam.in_view(cell.fiducials).all()
        assert cam.in_view(cell.block.corners()).all()
        assert 1.5 <= np.linalg.norm(cam.position - cell.work_centre) <= 2.0
    tool = Puma560Kinematics(tool_transform(0.1)).fk(NAMED_POSES["qn"])[:3, 3]
    assert cell.rig.left.in_view(tool[None]).all() and cell.rig.right.in_view(tool[None]).all()


def test_fiducials_are_non_coplanar_and_about_20_cm_apart() -> None:
    f = default_workcell().fiducials
    volume = abs(np.linalg.det(np.vstack([f[1] - f[0], f[2] - f[0], f[3] - f[0]])))
    assert volume > 1e-3
    assert np.linalg.norm(f[1:4] - f[0], axis=1) == pytest.approx([0.2, 0.2, 0.2])
    assert np.ptp(f[:8], axis=0) == pytest.approx([0.2, 0.2, 0.2])  # then the cube's corners
    assert len(f) == 12 and np.ptp(f[8:], axis=0)[:2] == pytest.approx([0.56, 0.9])


@pytest.mark.parametrize("baseline", [0.065, 0.12, 0.3])
def test_rig_is_rectified_with_the_configured_baseline(baseline: float) -> None:
    cell = default_workcell(baseline=baseline)
    assert cell.rig.baseline == pytest.approx(baseline)
    uv_l, uv_r = cell.rig.left.project(cell.fiducials), cell.rig.right.project(cell.fiducials)
    np.testing.assert_allclose(uv_l[:, 1], uv_r[:, 1], atol=1e-9)  # same rows
    assert np.all(uv_l[:, 0] > uv_r[:, 0])  # positive disparity
    # Depth from disparity matches the ground truth: Z = f·B / d.
    z = cell.rig.left.to_camera(cell.fiducials)[:, 2]
    f = cell.rig.left.K[0, 0]
    np.testing.assert_allclose(f * baseline / (uv_l[:, 0] - uv_r[:, 0]), z, rtol=1e-9)


def test_projection_matrix_agrees_with_project() -> None:
    cam = default_workcell().rig.left
    X = np.array([[0.6, -0.1, 0.5], [0.9, 0.2, 0.41]])
    h = (cam.P @ np.hstack([X, np.ones((2, 1))]).T).T
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], cam.project(X), atol=1e-9)
    np.testing.assert_allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(cam.R) == pytest.approx(1.0)


def test_points_behind_the_camera_do_not_project() -> None:
    cam = PinholeCamera.look_at("c", np.array([2.0, 0, 1]), np.array([0.0, 0, 1]))
    assert np.isnan(cam.project(np.array([[3.0, 0, 1]]))).all()
    assert cam.project(np.array([[0.0, 0, 1]]))[0] == pytest.approx([640, 360])


def test_contact_with_table_and_block() -> None:
    cell = default_workcell()
    top = cell.table.upper[2]
    box, depth, normal = cell.contact(np.array([0.9, 0.2, top - 0.004]))
    assert (
        box is cell.table and depth == pytest.approx(0.004) and normal == pytest.approx([0, 0, 1])
    )
    side = cell.block.lower[0]
    box, depth, normal = cell.contact(
        np.array([side + 0.002, cell.block.centre[1], cell.block.centre[2]])
    )
    assert (
        box is cell.block and depth == pytest.approx(0.002) and normal == pytest.approx([-1, 0, 0])
    )
    assert cell.contact(np.array([0.7, 0.0, top + 0.01]))[0] is None


def test_bad_camera_geometry_is_refused() -> None:
    with pytest.raises(InvalidCommand):
        stereo_rig(np.zeros(3), distance=0.0)
    with pytest.raises(InvalidCommand):
        PinholeCamera.look_at("c", np.zeros(3), np.zeros(3))
