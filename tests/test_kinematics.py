from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telerobot.drivers.base import InvalidCommand, JointLimitError, UnreachablePose
from telerobot.drivers.robot.puma560.kinematics import (
    DH,
    NAMED_POSES,
    QLIM,
    Puma560Kinematics,
    check_rotation,
    check_vector,
    tool_transform,
)


def dh_product(q: np.ndarray) -> np.ndarray:
    """Independent standard-DH forward kinematics, to check the Pinocchio model."""
    T = np.eye(4)
    for qi, (d, a, alpha) in zip(q, DH, strict=True):
        ct, st_, ca, sa = math.cos(qi), math.sin(qi), math.cos(alpha), math.sin(alpha)
        T = T @ np.array(
            [
                [ct, -st_ * ca, st_ * sa, a * ct],
                [st_, ct * ca, -ct * sa, a * st_],
                [0, sa, ca, d],
                [0, 0, 0, 1],
            ]
        )
    return T


@pytest.fixture
def kin() -> Puma560Kinematics:
    return Puma560Kinematics()


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("qz", (0.4521, -0.150, 1.1036)),
        ("qr", (0.0203, -0.150, 1.5354)),
        ("qs", (0.8636, -0.150, 0.6515)),
        ("qn", (0.5963, -0.150, 0.6575)),
    ],
)
def test_wrist_centre_of_named_poses(
    kin: Puma560Kinematics, name: str, expected: tuple[float, ...]
) -> None:
    assert kin.wrist_centre(NAMED_POSES[name]) == pytest.approx(expected, abs=1.5e-4)
    assert kin.within_limits(NAMED_POSES[name])


def test_pinocchio_model_matches_the_dh_table(kin: Puma560Kinematics) -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.uniform(QLIM[:, 0], QLIM[:, 1])
        np.testing.assert_allclose(kin.fk(q), dh_product(q), atol=1e-12)


def test_tool_transform_is_applied_after_the_flange() -> None:
    kin = Puma560Kinematics(tool_transform(0.15))
    q = NAMED_POSES["qn"]
    np.testing.assert_allclose(kin.fk(q), kin.fk_flange(q) @ tool_transform(0.15), atol=1e-12)
    assert np.linalg.norm(kin.fk(q)[:3, 3] - kin.wrist_centre(q)) == pytest.approx(0.15)


def test_jacobian_matches_finite_differences() -> None:
    kin = Puma560Kinematics(tool_transform(0.1))
    q = NAMED_POSES["qn"] + 0.2
    J = kin.jacobian(q).copy()
    h = 1e-7
    T0 = kin.fk(q).copy()
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        T1 = kin.fk(q + dq).copy()
        v = (T1[:3, 3] - T0[:3, 3]) / h
        dR = (T1[:3, :3] - T0[:3, :3]) / h @ T0[:3, :3].T  # skew(ω)
        w = np.array([dR[2, 1], dR[0, 2], dR[1, 0]])
        np.testing.assert_allclose(J[:3, i], v, atol=1e-5)
        np.testing.assert_allclose(J[3:, i], w, atol=1e-5)


def test_ik_gives_eight_distinct_configurations_that_all_reach_the_pose(
    kin: Puma560Kinematics,
) -> None:
    q = np.array([0.3, 0.5, -2.0, 0.4, 0.8, -0.3])
    T = kin.fk(q).copy()
    sols = kin.ik_all(T)
    assert sols.q.shape == (8, 6) and sols.reachable.all()
    configs = {kin.configuration(s) for s in sols.q}
    assert len(configs) == 8  # arm × elbow × wrist
    for s in sols.q:
        np.testing.assert_allclose(kin.fk(s), T, atol=1e-10)


def test_configuration_labels_of_known_poses(kin: Puma560Kinematics) -> None:
    c = kin.configuration(NAMED_POSES["qn"])
    assert (c.arm, c.wrist) == ("right", "noflip")
    assert kin.configuration(np.array([0, 0.5, -1.0, 0, -0.5, 0])).wrist == "flip"


def test_round_trip_over_random_poses_recovers_the_start(kin: Puma560Kinematics) -> None:
    rng = np.random.default_rng(42)
    worst = 0.0
    for _ in range(1000):
        q = rng.uniform(QLIM[:, 0], QLIM[:, 1])
        T = kin.fk(q).copy()
        sols = kin.ik_all(T, q)
        for s in sols.q[sols.reachable]:
            worst = max(worst, float(np.abs(kin.fk(s) - T).max()))
        np.testing.assert_allclose(kin.ik(T, q), q, atol=1e-7)
    assert worst < 1e-9


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6))
def test_nearest_ik_of_fk_returns_the_joints(fractions: list[float]) -> None:
    kin = Puma560Kinematics(tool_transform(0.1))
    q = QLIM[:, 0] + np.array(fractions) * (QLIM[:, 1] - QLIM[:, 0])
    T = kin.fk(q).copy()
    q2 = kin.ik(T, q)
    np.testing.assert_allclose(kin.fk(q2), T, atol=1e-9)
    assert kin.within_limits(q2)
    if abs(math.sin(q[4])) > 1e-6:  # away from the wrist singularity the joints are unique
        np.testing.assert_allclose(q2, q, atol=1e-6)


def test_wrist_singularity_keeps_q4_and_reaches_the_pose(kin: Puma560Kinematics) -> None:
    q = np.array([0.2, 0.4, -1.5, 0.0, 0.0, 0.0])
    T = kin.fk(q).copy()
    seed = np.array([0.2, 0.4, -1.5, 0.7, 0.01, 0.0])  # the arm's q4 is 0.7 now
    q2 = kin.ik(T, seed)
    assert q2[3] == pytest.approx(0.7)  # the wrist does not spin to reach a singular pose
    assert q2[4] == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(kin.fk(q2), T, atol=1e-10)
    for s in (1e-7, 1e-10, 1e-13):  # near the singularity, every solution still reaches the pose
        qs = np.array([0.2, 0.4, -1.5, 0.3, s, 0.1])
        Ts = kin.fk(qs).copy()
        sols = kin.ik_all(Ts, qs)
        for sol in sols.q[sols.reachable]:
            np.testing.assert_allclose(kin.fk(sol), Ts, atol=1e-9)


def test_joint_6_range_beyond_a_turn_is_used(kin: Puma560Kinematics) -> None:
    q = np.array([0.1, 0.3, -1.2, 0.2, 0.6, math.radians(250)])  # q6 past +180°
    q2 = kin.ik(kin.fk(q).copy(), q)
    assert q2[5] == pytest.approx(q[5], abs=1e-7)


def test_unreachable_pose_is_refused(kin: Puma560Kinematics) -> None:
    T = np.eye(4)
    T[:3, 3] = [2.0, 0.0, 0.7]
    with pytest.raises(UnreachablePose, match="outside the PUMA 560's reach"):
        kin.ik(T, NAMED_POSES["qn"])
    T[:3, 3] = [0.0, 0.0, 0.9]  # inside the shoulder's cylinder of radius d3
    with pytest.raises(UnreachablePose):
        kin.ik(T, NAMED_POSES["qn"])


def test_pose_reachable_only_past_the_limits_is_refused(kin: Puma560Kinematics) -> None:
    q = np.array([-2.603, -1.654, 1.893, 0.516, -2.55, -0.42])  # outside the limits
    with pytest.raises(JointLimitError, match="past a joint limit"):
        kin.ik(kin.fk(q).copy(), NAMED_POSES["qn"])


def test_check_joint_limits_names_the_joint(kin: Puma560Kinematics) -> None:
    with pytest.raises(JointLimitError, match="joint 2"):
        kin.check_joint_limits(np.array([0, math.radians(230), 0, 0, 0, 0]))


@pytest.mark.parametrize(
    "value",
    [
        [1, 2, 3],
        [1, 2, 3, 4, 5, 6, 7],
        [0, 0, math.nan, 0, 0, 0],
        [0, 0, 0, math.inf, 0, 0],
        "abc",
        None,
    ],
)
def test_bad_vectors_are_refused(value: object) -> None:
    with pytest.raises(InvalidCommand):
        check_vector("joints", value, 6)


def test_bad_rotations_are_refused() -> None:
    with pytest.raises(InvalidCommand, match="not a rotation"):
        check_rotation("R", np.eye(3) * 2)
    with pytest.raises(InvalidCommand, match="not a rotation"):
        check_rotation("R", np.diag([1.0, 1.0, -1.0]))  # a reflection
    with pytest.raises(InvalidCommand, match="3x3"):
        check_rotation("R", np.eye(4))
    check_rotation("R", np.eye(3))


def test_fast_path_picks_the_same_solution_as_comparing_all_eight() -> None:
    kin = Puma560Kinematics(tool_transform(0.1))
    rng = np.random.default_rng(7)
    for _ in range(500):
        q = rng.uniform(QLIM[:, 0], QLIM[:, 1])
        dq = rng.normal(0, 0.02 if _ % 2 else 0.6, 6)  # teleoperation steps, and big jumps
        T = kin.fk(np.clip(q + dq, QLIM[:, 0], QLIM[:, 1])).copy()
        sols = kin.ik_all(T, q)
        fitted = [kin.fit_limits(s, q) for s in sols.q[sols.reachable]]
        best = min((f for f in fitted if f is not None), key=lambda f: float(np.sum((f - q) ** 2)))
        np.testing.assert_allclose(kin.ik(T, q), best, atol=1e-9)
