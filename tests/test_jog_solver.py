"""The jog solver (issue 50): ``jog(T, seed)``, differential inverse kinematics for
small Cartesian increments, on both arms: the PUMA 560 (six joints, closed-form ``ik``)
and the SO-101 (five joints in the tool's chain, numeric ``ik``). Behaviour only: what
it reaches, what it keeps, what it refuses, and how it compares with ``ik``; how long
it takes is bench.kinematics' and bench.command_latency's (docs/PERFORMANCE.md)."""

from __future__ import annotations

import contextlib
import math

import numpy as np
import pinocchio as pin
import pytest

from telerobot.drivers.base import (
    FloatArray,
    JointLimitError,
    TelerobotError,
    UnreachablePose,
    WorkingFrame,
)
from telerobot.drivers.robot.kinematics import PinocchioKinematics, tool_transform
from telerobot.drivers.robot.models import RobotModel, load_model

MODELS = ("so101", "puma560")
STEP_M = 0.0002  # the page's jog increment: 0.2 mm
POSITION_TOL_M = 1e-6  # what ik meets (UrdfKinematics.position_tol_m), and jog with it
ORIENTATION_TOL_RAD = 1e-5
JOINT_STEP_RAD = 0.10  # the server's max_joint_step_rad: a larger jump is refused


def kinematics(model: RobotModel, tool: FloatArray | None = None) -> PinocchioKinematics:
    kin = model.kinematics(tool_transform(model.default_tool_length) if tool is None else tool)
    assert isinstance(kin, PinocchioKinematics)
    return kin


def rotation_error(A: FloatArray, B: FloatArray) -> float:
    return float(np.linalg.norm(pin.log3(A[:3, :3].T @ B[:3, :3])))


def position_error(A: FloatArray, B: FloatArray) -> float:
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3]))


def unit(rng: np.random.Generator) -> FloatArray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def near_home(model: RobotModel, rng: np.random.Generator, spread: float = 0.25) -> FloatArray:
    """Joints about the home pose, a tenth of each range clear of the limits."""
    lo, hi = model.qlim[:, 0], model.qlim[:, 1]
    margin = 0.1 * (hi - lo)
    q = model.pose(model.home_pose) + rng.normal(0.0, spread, model.dof)
    return np.clip(q, lo + margin, hi - margin)


def increment(
    kin: PinocchioKinematics,
    q: FloatArray,
    rng: np.random.Generator,
    *,
    rotation_rad: float = 0.0,
) -> FloatArray:
    """The tool pose after a 0.2 mm increment in a random direction, in the base or the
    tool frame at random (and a rotation of ``rotation_rad`` about a random axis)."""
    frame = WorkingFrame.BASE if rng.random() < 0.5 else WorkingFrame.TOOL
    dM = pin.exp3(rotation_rad * unit(rng))
    return kin.apply_increment(kin.fk(q).copy(), STEP_M * unit(rng), dM, frame)


def constrained_optimum(kin: PinocchioKinematics, T: FloatArray, q: FloatArray) -> float:
    """The least orientation error of a tool at ``T``'s position near ``q``: the
    position weighted 10⁴ times the orientation, Levenberg-Marquardt to convergence
    (independent of the jog's own steps). Returns NaN if it left the position short."""
    lo, hi = kin.qlim[:, 0], kin.qlim[:, 1]
    scale = np.array([1e4] * 3 + [1.0] * 3)

    def error(q: FloatArray) -> tuple[FloatArray, FloatArray]:
        J = kin.jacobian(q)
        M = kin.fk(q)
        e_p = T[:3, 3] - M[:3, 3]
        e_o = M[:3, :3] @ pin.log3(M[:3, :3].T @ T[:3, :3])
        return J * scale[:, None], np.concatenate([e_p, e_o]) * scale

    J, e = error(q)
    mu = 1e-4
    for _ in range(300):
        dq = np.linalg.solve(J.T @ J + mu * np.eye(len(q)), J.T @ e)
        q_next = np.clip(q + dq, lo, hi)
        J_next, e_next = error(q_next)
        if e_next @ e_next < e @ e:
            q, J, e, mu = q_next, J_next, e_next, max(mu / 3, 1e-12)
        else:
            mu *= 5
        if np.abs(dq).max() < 1e-12:
            break
    M = kin.fk(q)
    return rotation_error(M, T) if position_error(M, T) < 1e-7 else math.nan


@pytest.mark.parametrize("name", MODELS)
def test_small_increments_in_random_directions_are_met_in_a_step_or_two(name: str) -> None:
    model = load_model(name)
    kin = kinematics(model)
    rng = np.random.default_rng(50)
    steps: list[int] = []
    for _ in range(300):
        q = near_home(model, rng)
        T = increment(kin, q, rng)
        found = kin.jog(T, q)
        reached = kin.fk(found)
        assert position_error(reached, T) <= POSITION_TOL_M
        assert kin.within_limits(found)
        assert kin.last_jog_steps is not None  # met by the jog itself, not its fallback
        steps.append(kin.last_jog_steps)
        assert kin.last_jog_residual[0] == pytest.approx(position_error(reached, T), abs=1e-12)
        if name == "so101":
            assert found[5] == q[5]  # the gripper is not in the tool's chain
    # One Jacobian solve for nearly every 0.2 mm increment, two at most here.
    assert max(steps) <= 2 and steps.count(1) >= 0.95 * len(steps)


@pytest.mark.parametrize("name", MODELS)
def test_larger_increments_and_rotations_are_met_within_the_steps(name: str) -> None:
    # Up to the largest a command may ask (20 mm and 0.1 rad at once).
    model = load_model(name)
    kin = kinematics(model)
    rng = np.random.default_rng(51)
    for size, angle in ((0.002, 0.0), (0.02, 0.0), (0.0, 0.01), (0.0, 0.1), (0.02, 0.1)):
        for _ in range(40):
            q = near_home(model, rng, spread=0.15)
            frame = WorkingFrame.BASE if rng.random() < 0.5 else WorkingFrame.TOOL
            T0 = kin.fk(q).copy()
            T = kin.apply_increment(T0, size * unit(rng), pin.exp3(angle * unit(rng)), frame)
            found = kin.jog(T, q)
            assert position_error(kin.fk(found), T) <= POSITION_TOL_M
            assert kin.within_limits(found)
            assert kin.last_jog_steps is not None and kin.last_jog_steps <= 3


def test_the_puma_keeps_its_orientation_and_agrees_with_its_closed_form() -> None:
    model = load_model("puma560")
    kin = kinematics(model)
    rng = np.random.default_rng(52)
    lo, hi = model.qlim[:, 0], model.qlim[:, 1]
    compared = 0
    for _ in range(300):
        q = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
        if abs(math.sin(q[4])) < 0.2:  # the wrist singularity: its own test below
            continue
        T = increment(kin, q, rng, rotation_rad=0.002 * rng.random())
        try:
            closed = kin.ik(T, q)
        except TelerobotError as exc:
            with pytest.raises(type(exc)):
                kin.jog(T, q)
            continue
        found = kin.jog(T, q)
        reached = kin.fk(found)
        assert position_error(reached, T) <= POSITION_TOL_M
        assert rotation_error(reached, T) <= ORIENTATION_TOL_RAD
        assert kin.within_limits(found)
        if np.abs(closed - q).max() <= JOINT_STEP_RAD:  # both a small move: the same one,
            # to what the pose's tolerance allows (more near the elbow's singularity)
            np.testing.assert_allclose(found, closed, atol=1e-3)
            compared += 1
    assert compared > 200


def test_the_puma_at_its_wrist_singularity_answers_as_its_closed_form() -> None:
    # 0.6° about the tool's x axis next to the wrist singularity needs q4 and q6 to
    # swing ~90° (the server's joint-step limit refuses it): the jog cannot hold that
    # orientation with small steps and, the PUMA's ik meeting the whole pose, answers
    # what ik answers.
    model = load_model("puma560")
    kin = kinematics(model)
    q = model.pose("qn")
    q[4] = 1e-4
    T = kin.fk(q) @ np.block(
        [[pin.exp3(np.array([0.01, 0.0, 0.0])), np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]]
    )
    found = kin.jog(T, q)
    assert kin.last_jog_steps is None  # it went to ik
    np.testing.assert_array_equal(found, kin.ik(T, q))
    assert np.abs(found - q).max() > JOINT_STEP_RAD


def test_the_so101_keeps_its_position_and_turns_only_as_much_as_it_must() -> None:
    model = load_model("so101")
    kin = kinematics(model)
    rng = np.random.default_rng(53)
    turned = compared = 0
    for _ in range(150):
        q = near_home(model, rng)
        T = increment(kin, q, rng)
        found = kin.jog(T, q)
        reached = kin.fk(found)
        assert position_error(reached, T) <= POSITION_TOL_M
        error = rotation_error(reached, T)
        assert error == pytest.approx(kin.last_jog_residual[1], abs=1e-12)
        assert error < 0.01  # a 0.2 mm move turns the tool by milliradians at most
        turned += error > ORIENTATION_TOL_RAD
        best = constrained_optimum(kin, T, q)
        if not math.isnan(best):
            assert error <= best + ORIENTATION_TOL_RAD  # as near as its joints allow
            compared += 1
    assert turned > 50  # most directions: five joints cannot keep the orientation
    assert compared > 100


def test_the_so101_sideways_from_home_turns_the_tool_the_least_and_ik_agrees() -> None:
    # From the home pose (gripper down, pan 0): x and z are in the arm's plane, met
    # with the orientation kept; y (sideways) turns the tool.
    model = load_model("so101")
    kin = kinematics(model)
    q = model.pose(model.home_pose)
    for axis in range(3):
        for sign in (1.0, -1.0):
            T = kin.fk(q).copy()
            T[axis, 3] += sign * STEP_M
            found = kin.jog(T, q)
            assert kin.last_jog_steps == 1
            reached, by_ik = kin.fk(found), kin.fk(kin.ik(T, q))
            assert position_error(reached, T) <= POSITION_TOL_M
            if axis == 1:
                assert 1e-4 < rotation_error(reached, T) < 1e-3
                # ik's position-only fallback: no nearer than the jog
                assert rotation_error(reached, T) <= rotation_error(by_ik, T) + 1e-7
            else:
                assert rotation_error(reached, T) <= ORIENTATION_TOL_RAD
                np.testing.assert_allclose(found, kin.ik(T, q), atol=1e-6)


def test_the_so101_agrees_with_ik_where_both_apply() -> None:
    model = load_model("so101")
    kin = kinematics(model)
    rng = np.random.default_rng(54)
    exact = other = 0
    for i in range(300):
        q = near_home(model, rng)
        if i % 3 == 0:  # along the base's z: in the arm's plane, often met exactly
            T = kin.fk(q).copy()
            T[2, 3] += STEP_M
        else:
            T = increment(kin, q, rng)
        found = kin.jog(T, q)
        by_ik = kin.ik(T, q)
        if np.abs(by_ik - q).max() > JOINT_STEP_RAD:
            continue  # ik took another configuration: the server refuses that jump
        reached, ik_reached = kin.fk(found), kin.fk(by_ik)
        assert position_error(reached, T) <= POSITION_TOL_M
        if rotation_error(ik_reached, T) <= ORIENTATION_TOL_RAD:  # the whole pose reached
            np.testing.assert_allclose(found, by_ik, atol=1e-4)
            exact += 1
        else:  # the position, the orientation as near as the arm can: no worse than ik
            assert rotation_error(reached, T) <= rotation_error(ik_reached, T) + 1e-5
            other += 1
    assert exact > 30 and other > 100


@pytest.mark.parametrize("name", MODELS)
def test_an_increment_past_a_joint_limit_is_handled_as_ik_handles_it(name: str) -> None:
    """Each joint at each of its limits in the home pose, the tool moved 0.2 mm the way
    that joint would carry it further: the SO-101 holds the joint at its limit and
    meets the position with the others (as its ik does), the PUMA answers what its
    closed form answers (another configuration, which the server's joint-step limit
    refuses, or JointLimitError)."""
    model = load_model(name)
    kin = kinematics(model)
    home = model.pose(model.home_pose)
    held = 0
    for j in range(model.dof):
        for end, sign in ((0, -1.0), (1, 1.0)):
            q = home.copy()
            q[j] = model.qlim[j, end]
            column = kin.jacobian(q)[:3, j]
            if np.linalg.norm(column) < 1e-6:  # the gripper: moves no tool point
                continue
            T = kin.fk(q).copy()
            T[:3, 3] += STEP_M * sign * column / np.linalg.norm(column)
            try:
                by_ik = kin.ik(T, q)
            except (UnreachablePose, JointLimitError) as exc:
                with pytest.raises(type(exc)):
                    kin.jog(T, q)
                continue
            found = kin.jog(T, q)
            assert kin.within_limits(found)
            assert position_error(kin.fk(found), T) <= POSITION_TOL_M
            np.testing.assert_allclose(found, by_ik, atol=1e-4)
            held += found[j] == model.qlim[j, end]
    if name == "so101":
        assert held >= 2  # some joints are held exactly at their limits
    else:
        assert held == 0  # the closed form never holds: another configuration or refused


def test_the_so101_holds_a_joint_at_its_limit_and_meets_the_position_with_the_others() -> None:
    model = load_model("so101")
    kin = kinematics(model)
    rng = np.random.default_rng(55)
    lo, hi = model.qlim[:, 0], model.qlim[:, 1]
    for _ in range(200):
        q = near_home(model, rng)
        j = int(rng.integers(0, 5))
        end = int(rng.integers(0, 2))
        q[j] = model.qlim[j, end]
        T = increment(kin, q, rng)
        try:
            found = kin.jog(T, q)
        except UnreachablePose:
            # Refused only where ik finds no small move either.
            with contextlib.suppress(UnreachablePose):
                assert np.abs(kin.ik(T, q) - q).max() > JOINT_STEP_RAD
            continue
        assert np.all(found >= lo) and np.all(found <= hi)  # exactly, no tolerance
        assert position_error(kin.fk(found), T) <= POSITION_TOL_M


@pytest.mark.parametrize("name", MODELS)
def test_out_of_reach_is_refused_as_ik_refuses_it(name: str) -> None:
    model = load_model(name)
    kin = kinematics(model)
    q = model.pose(model.home_pose)
    far = kin.fk(q).copy()
    far[:3, 3] = (2.5, 0.0, 0.5)
    with pytest.raises(UnreachablePose) as by_ik:
        kin.ik(far, q)
    with pytest.raises(UnreachablePose) as by_jog:
        kin.jog(far, q)
    assert str(by_jog.value) == str(by_ik.value)


@pytest.mark.parametrize("name", MODELS)
def test_jogging_out_to_the_edge_of_the_reach_is_refused_never_approximated(name: str) -> None:
    # Outward along the base's x in 2 mm increments from the home pose until the arm
    # refuses (or would jump further than the server lets one increment move a joint):
    # every answer before meets its position; the refusal is ik's.
    model = load_model(name)
    kin = kinematics(model)
    q = model.pose(model.home_pose)
    for _ in range(1000):
        T = kin.fk(q).copy()
        T[0, 3] += 0.002
        try:
            found = kin.jog(T, q)
        except (UnreachablePose, JointLimitError) as exc:
            try:
                assert np.abs(kin.ik(T, q) - q).max() > JOINT_STEP_RAD
            except TelerobotError as by_ik:
                assert isinstance(by_ik, type(exc)) or isinstance(exc, type(by_ik))
            break
        assert position_error(kin.fk(found), T) <= POSITION_TOL_M
        assert kin.within_limits(found)
        if np.abs(found - q).max() > JOINT_STEP_RAD:
            break  # the stretched arm's singularity: the server refuses this jump
        q = found
    else:
        pytest.fail("the arm never reached the edge of its reach")


@pytest.mark.parametrize("name", MODELS)
def test_a_tool_with_an_offset_and_a_rotation_is_jogged_at_its_own_point(name: str) -> None:
    # The Jacobian's axes and point must be the tool's (base-aligned, at the tool point).
    model = load_model(name)
    tool = tool_transform(0.07)
    tool[:3, :3] = pin.exp3(np.array([0.3, -0.5, 0.8]))
    tool[:3, 3] += (0.02, -0.01, 0.0)
    kin = kinematics(model, tool)
    rng = np.random.default_rng(57)
    for _ in range(100):
        q = near_home(model, rng)
        T = increment(kin, q, rng, rotation_rad=0.001)
        found = kin.jog(T, q)
        reached = kin.fk(found)
        assert position_error(reached, T) <= POSITION_TOL_M
        assert kin.last_jog_steps is not None and kin.last_jog_steps <= 2
        if name == "puma560":
            assert rotation_error(reached, T) <= ORIENTATION_TOL_RAD


@pytest.mark.parametrize("name", MODELS)
def test_no_increment_returns_the_seed_and_never_aliases_it(name: str) -> None:
    model = load_model(name)
    kin = kinematics(model)
    q = model.pose(model.home_pose)
    found = kin.jog(kin.fk(q).copy(), q)
    assert kin.last_jog_steps == 0
    np.testing.assert_array_equal(found, q)
    found[0] += 1.0
    assert q[0] == model.pose(model.home_pose)[0]
