from __future__ import annotations

import numpy as np
import pytest

from telerobot.drivers.robot.motion import (
    PUMA_AMAX,
    PUMA_STOP_DECEL,
    PUMA_VMAX,
    JointMotion,
    StopRamp,
    SyncMove,
    cartesian_stop,
    move_duration,
    stop_distance,
    stop_time,
    trapezoid_time,
)


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
    assert m.q[0] == pytest.approx(q + v * v / (2 * PUMA_STOP_DECEL[0]), abs=1e-9)


def test_brake_decelerates_at_the_stop_limit_all_joints_together() -> None:
    m = JointMotion(np.zeros(6))
    m.set_target(np.array([3.0, -1.5, 0.8, 4.0, 0.0, -2.0]))
    m.advance(1.2)  # joint 1 cruising at 1 rad/s, the others in proportion
    q0, v0 = m.q, m.v
    assert v0[0] == pytest.approx(1.0)
    T = stop_time(v0, PUMA_STOP_DECEL)
    assert pytest.approx(max(np.abs(v0) / PUMA_STOP_DECEL)) == T
    m.brake()
    m.advance(T / 2)
    # Uniform deceleration: every joint at half its speed half way, the slowest joint
    # (here joint 1, 1 rad/s at 10 rad/s²) braking at exactly its limit.
    np.testing.assert_allclose(m.v, v0 / 2, atol=1e-12)
    _, apeak = run(m, T / 2 - 0.002)
    assert m.moving and apeak[0] == pytest.approx(PUMA_STOP_DECEL[0], rel=1e-6)
    assert np.all(apeak <= PUMA_STOP_DECEL + 1e-6)
    run(m, 0.003)
    assert not m.moving and not m.stopping
    np.testing.assert_allclose(m.q, q0 + stop_distance(v0, PUMA_STOP_DECEL), atol=1e-12)
    np.testing.assert_allclose(m.target, m.q, atol=1e-12)
    assert pytest.approx(0.1) == T  # full speed to rest in 0.1 s (was 0.5 s)


def test_a_new_target_during_a_stop_carries_on_from_the_current_velocity() -> None:
    m = JointMotion(np.zeros(6))
    m.set_target(np.array([3.0, 0, 0, 0, 0, 0]))
    m.advance(1.0)
    m.brake()
    m.advance(0.03)
    v = m.v[0]
    m.set_target(np.array([3.0, 0, 0, 0, 0, 0]))
    assert not m.stopping
    _, apeak = run(m, 0.01)
    assert m.v[0] == pytest.approx(v + 0.01 * PUMA_AMAX[0], abs=1e-9)  # no jump
    assert apeak[0] <= PUMA_AMAX[0] + 1e-6


def test_stop_ramp_is_exact() -> None:
    ramp = StopRamp([0.0, 1.0], [1.0, -0.5], np.array([10.0, 10.0]))
    assert ramp.duration == pytest.approx(0.1)
    q, v = ramp.at(0.05)
    assert v == pytest.approx([0.5, -0.25])
    assert q == pytest.approx([0.05 - 0.5 * 10 * 0.05**2, 1.0 - 0.5 * (0.05 - 0.5 * 10 * 0.05**2)])
    q, v = ramp.at(1.0)
    assert q == pytest.approx([0.05, 0.975]) and v == [0.0, 0.0]


@pytest.mark.parametrize("distance", [0.05, 2.0])  # triangular, trapezoidal
def test_sync_move_follows_the_trapezoid_and_arrives_together(distance: float) -> None:
    q0 = np.array([0.1, 0.2, -0.3, 0.0, 0.5, 0.0])
    q1 = q0 + np.array([distance, -distance / 2, 0.0, distance, 0.0, 0.1])
    move = SyncMove(q0, q1, PUMA_VMAX, PUMA_AMAX)
    assert move.duration == pytest.approx(move_duration(q0, q1, PUMA_VMAX, PUMA_AMAX))
    np.testing.assert_allclose(move.at(0.0)[0], q0)
    np.testing.assert_allclose(move.at(move.duration)[0], q1, atol=1e-12)
    prev_t, (prev_q, prev_v) = 0.0, move.at(0.0)
    for t in np.linspace(0.001, move.duration, 400):
        q, v = move.at(float(t))
        dt = float(t) - prev_t
        assert np.all(np.abs(v) <= PUMA_VMAX + 1e-9)
        assert np.all(np.abs(v - prev_v) <= PUMA_AMAX * dt + 1e-9)
        np.testing.assert_allclose(q - prev_q, (v + prev_v) / 2 * dt, atol=4.0 * dt * dt)
        prev_t, prev_q, prev_v = float(t), q, v


def test_cartesian_stop_takes_the_worst_direction() -> None:
    J = np.diag([0.5, 0.5, 0.5, 1.0, 1.0, 1.0])  # joint i moves the tool along axis i
    time, distance = cartesian_stop(J, 0.25, PUMA_STOP_DECEL, PUMA_VMAX)
    assert time == pytest.approx(0.5 / 10)  # 0.25 m/s needs 0.5 rad/s on one joint
    assert distance == pytest.approx(0.25 * time / 2)
    # Faster than a joint can turn: its speed limit bounds the stop.
    assert cartesian_stop(J, 5.0, PUMA_STOP_DECEL, PUMA_VMAX)[0] == pytest.approx(0.1)
