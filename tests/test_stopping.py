"""Stopping time and distance: a stop decelerates at the drives' limit,
all joints together, and ends within the time and distance the server states
(GET /api/v1/safety), on the simulated arm in virtual time."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from telerobot.drivers.base import StopCategory
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.robot.motion import PUMA_STOP_DECEL, PUMA_VMAX, cartesian_stop, stop_time
from telerobot.drivers.robot.puma560.kinematics import (
    NAMED_POSES,
    Puma560Kinematics,
    tool_transform,
)
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.limits import SafetyLimits, full_speed_stop_s, stopping
from tests.support import TOKEN
from tests.support.clock import run_with_clock

LOW = np.array([0.5, 0.9, -2.6, 0.3, 0.5, 0.0])  # bench.stopping's second pose


async def drive_then_lose_the_link(
    q0: np.ndarray, direction: list[float], speed: float
) -> tuple[SimPuma, DecisionServer, dict[str, Any]]:
    """Drive the tool at ``speed`` for 0.5 s with 100 increments a second, then the
    controller disconnects (the lease lapses: a stop). Returns what happened."""
    clock = ManualClock()
    robot = SimPuma(clock=clock, kinematics=Puma560Kinematics(tool_transform(0.1)), start_joints=q0)
    await robot.connect()
    await run_with_clock(clock, robot.initialize(q0))
    ds = DecisionServer(
        [ArmGuard("arm", 1, robot, Puma560Kinematics(tool_transform(0.1)), SafetyLimits())],
        clock=clock,
        operator_token=TOKEN,
    )
    client = ds.join("op", TOKEN)
    await ds.take_lease(client.id)
    step = np.array(direction, dtype=float) * speed * 0.01
    for _ in range(50):
        await clock.advance(0.01)
        await ds.cartesian_increment(client.id, step, np.zeros(3))
    p0, v0 = robot.pose.position, robot.joint_velocities
    p_before = robot.kinematics.fk(robot.joints - v0 * 0.001)[:3, 3]
    t0 = clock.now()
    await ds.leave(client.id)  # the link is gone: the lease lapses, the arm stops
    rest = None
    peak_decel = np.zeros(6)
    prev = v0
    while clock.now() - t0 < 1.0:
        await clock.advance(0.001)
        v = robot.joint_velocities
        peak_decel = np.maximum(peak_decel, np.abs(v - prev) / 0.001)
        prev = v
        if rest is None and not np.any(v):
            rest = clock.now()
    assert rest is not None
    figures = {
        "p0": p0,
        "heading": p0 - p_before,
        "time_s": rest - t0,
        "distance_m": float(np.linalg.norm(robot.pose.position - p0)),
        "speed_m_s": float(np.linalg.norm(p0 - p_before) / 0.001),
        "expected_time_s": stop_time(v0, PUMA_STOP_DECEL),
    }
    figures["peak_decel_share"] = float(np.max(peak_decel / PUMA_STOP_DECEL))
    return robot, ds, figures


@pytest.mark.parametrize(
    ("pose", "direction"), [(NAMED_POSES["qn"], [0, 1, 0]), (LOW, [1, 0, 0])], ids=["qn", "low"]
)
@pytest.mark.parametrize("speed", [0.05, 0.1, 0.25])
async def test_a_stop_from_speed_ends_within_the_stated_time_and_distance(
    pose: np.ndarray, direction: list[float], speed: float
) -> None:
    robot, ds, got = await drive_then_lose_the_link(pose, direction, speed)
    # The slowest joint braked at its limit, none faster: the stop took exactly the
    # time of the joint velocities it started from, at the drives' deceleration.
    assert got["peak_decel_share"] == pytest.approx(1.0, abs=0.01)
    assert got["time_s"] == pytest.approx(got["expected_time_s"], abs=0.0015)
    # …and no more than what GET /api/v1/safety states for that speed there (worst
    # direction), for the speed the tool reached.
    spec = robot.stop_spec
    stated_time, stated_distance = cartesian_stop(
        ds.arms[0].kinematics.jacobian(robot.joints), got["speed_m_s"], spec.decel, spec.vmax
    )
    assert got["time_s"] <= stated_time + 0.0015
    assert got["distance_m"] <= stated_distance + 1e-4
    assert got["time_s"] < 0.11  # from any speed: 0.1 s at the limit (was 0.2-0.55 s)


@pytest.mark.parametrize(
    ("pose", "direction"), [(NAMED_POSES["qn"], [0, 1, 0]), (LOW, [1, 0, 0])], ids=["qn", "low"]
)
async def test_the_stop_keeps_the_tool_on_its_path(
    pose: np.ndarray, direction: list[float]
) -> None:
    robot, _, got = await drive_then_lose_the_link(pose, direction, 0.25)
    # Every joint brakes in proportion: the tool stops on the line it was moving along
    # when the link was lost, to within the curvature of a straight line in joint space
    # (joints braking each on their own at 2 rad/s² swung it 5-95 % of the way sideways).
    moved = robot.pose.position - got["p0"]
    u = got["heading"] / np.linalg.norm(got["heading"])
    sideways = float(np.linalg.norm(moved - (moved @ u) * u))
    assert sideways < 0.03 * float(np.linalg.norm(moved))


def test_the_stopping_table_covers_the_speeds_up_to_the_limit() -> None:
    kin = Puma560Kinematics(tool_transform(0.1))
    robot = SimPuma(kinematics=kin, start_joints=NAMED_POSES["qn"])
    limits = SafetyLimits()
    rows = stopping(limits, robot.stop_spec, kin.jacobian(NAMED_POSES["qn"]))
    assert [r.speed_m_s for r in rows] == [0.05, 0.1, 0.25]
    for r in rows:
        assert 0 < r.time_s <= 0.1 + 1e-9
        assert r.distance_m == pytest.approx(r.speed_m_s * r.time_s / 2)
        detect = limits.deadman_timeout_s + limits.tick_s
        assert r.after_silence_time_s == pytest.approx(detect + r.time_s)
        assert r.after_silence_distance_m == pytest.approx(r.speed_m_s * detect + r.distance_m)
    assert rows[0].time_s < rows[1].time_s < rows[2].time_s
    assert full_speed_stop_s(robot.stop_spec) == pytest.approx(0.1)


def test_at_a_singularity_the_joint_speed_limits_bound_the_stop() -> None:
    kin = Puma560Kinematics(tool_transform(0.1))
    time_s, _ = cartesian_stop(kin.jacobian(NAMED_POSES["qz"]), 0.25, PUMA_STOP_DECEL, PUMA_VMAX)
    assert 0 < time_s <= stop_time(PUMA_VMAX, PUMA_STOP_DECEL) + 1e-12


def test_get_safety_states_the_stop_category_and_the_stopping_figures(client: TestClient) -> None:
    body = client.get("/api/v1/safety").json()
    assert body["stop_category"] == int(StopCategory.CONTROLLED_HOLDING) == 2
    assert (
        "category 2" in body["stop_category_text"]
        and "hardware e-stop" in body["stop_category_text"]
    )
    assert body["stop_decel_rad_s2"] == PUMA_STOP_DECEL.tolist()
    assert body["stop_reaction_s"] == 0.0
    assert body["stopping_full_speed_s"] == pytest.approx(0.1)
    rows = body["stopping"]
    assert [r["speed_m_s"] for r in rows] == [0.05, 0.1, body["max_speed_m_s"]]
    kin = Puma560Kinematics(tool_transform(0.1))
    joints = np.array(client.get("/api/v1/robot/state").json()["joints"])
    for r in rows:
        t, d = cartesian_stop(kin.jacobian(joints), r["speed_m_s"], PUMA_STOP_DECEL, PUMA_VMAX)
        assert r["time_s"] == pytest.approx(t, rel=1e-6)
        assert r["distance_m"] == pytest.approx(d, rel=1e-6)
        assert r["after_silence_time_s"] > r["time_s"]
        assert r["after_silence_distance_m"] > r["distance_m"]
    # The figures are documented in the OpenAPI schema.
    schema = client.get("/openapi.json").json()["components"]["schemas"]
    assert "stopping" in schema["SafetyView"]["properties"]
