from __future__ import annotations

import numpy as np
import pytest

from drivers.robot.motion import PUMA_AMAX, PUMA_VMAX, JointMotion, move_duration, trapezoid_time


def test_trapezoid_time() -> None:
    assert trapezoid_time(0.0, 1.0, 2.0) == 0.0
    assert trapezoid_time(0.25, 1.0, 2.0) == pytest.approx(2 * np.sqrt(0.25 / 2))  # triangular
    assert trapezoid_time(-2.0, 1.0, 2.0) == pytest.approx(2.0 + 0.5)  # cruise + ramps


def run(m: JointMotion, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Step ``seconds`` in 1 ms and return the peak |v| and |a| per joint."""
    vmax = np.zeros(6)
    amax = np.zeros(6)
    prev = m.v
    for _ in range(round(seconds / 0.001)):
        m.advance(0.001)
        v = m.v
        vmax = np.maximum(vmax, np.abs(v))
        amax = np.maximum(amax, np.abs(v - prev) / 0.001)
        prev = v
    return vmax, amax


def test_move_respects_limits_arrives_and_takes_the_time_it_takes() -> None:
    m = JointMotion(np.zeros(6))
    target = np.array([1.0, -0.5, 0.2, 2.0, 0.0, -0.1])
    m.set_target(target)
    expected = move_duration(np.zeros(6), target, PUMA_VMAX, PUMA_AMAX)
    vpeak, apeak = run(m, expected * 0.9)
    assert m.moving  # not there yet at 90 % of the time
    vp2, ap2 = run(m, expected * 0.2)
    assert not m.moving
    np.testing.assert_allclose(m.q, target, atol=1e-9)
    assert np.all(np.maximum(vpeak, vp2) <= PUMA_VMAX + 1e-9)
    assert np.all(np.maximum(apeak, ap2) <= PUMA_AMAX + 1e-6)


def test_joints_are_synchronised() -> None:
    m = JointMotion(np.zeros(6))
    target = np.array([1.0, 0.5, 0, 0, 0, 0])
    m.set_target(target)
    for _ in range(700):
        m.advance(0.001)
        if abs(m.q[0]) > 1e-3:
            assert m.q[1] / m.q[0] == pytest.approx(0.5, rel=0.02)  # a straight line in joint space


def test_retarget_mid_motion_has_no_velocity_jump() -> None:
    m = JointMotion(np.zeros(6))
    m.set_target(np.array([1.0, 0, 0, 0, 0, 0]))
    m.advance(0.6)
    v_before = m.v[0]
    assert v_before > 0.5
    m.set_target(np.array([-0.5, 0, 0, 0, 0, 0]))  # reverse
    _, apeak = run(m, 4.0)
    assert apeak[0] <= PUMA_AMAX[0] + 1e-6
    assert not m.moving and m.q[0] == pytest.approx(-0.5)


def test_brake_comes_to_rest_within_the_stopping_distance() -> None:
    m = JointMotion(np.zeros(6))
    m.set_target(np.array([3.0, 0, 0, 0, 0, 0]))
    m.advance(1.0)
    q, v = m.q[0], m.v[0]
    m.brake()
    run(m, 2.0)
    assert not m.moving
    assert m.q[0] == pytest.approx(q + v * v / (2 * PUMA_AMAX[0]), abs=2e-3)
