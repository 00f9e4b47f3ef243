"""Pushing the simulated gripper into the table: the sensor feels it and the
DecisionServer's force limit stops the arm (virtual time, no threads)."""

from __future__ import annotations

import numpy as np
import pytest

from telerobot.drivers.clock import ManualClock
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.robot.puma560.kinematics import Puma560Kinematics, tool_transform
from telerobot.drivers.robot.puma560.sim import SimPuma
from telerobot.drivers.sim.workcell import default_workcell
from telerobot.server.control.arm_guard import ArmGuard
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import SafetyStop
from telerobot.server.control.limits import SafetyLimits
from tests.support import TOKEN
from tests.support.clock import run_with_clock
from tests.support.puma import joints_with_tip_at


async def test_pushing_into_the_table_trips_the_force_limit_and_backing_off_clears_it() -> None:
    clock = ManualClock()
    cell = default_workcell()
    top = cell.table.upper[2]
    start = joints_with_tip_at(np.array([0.8, 0.2, top + 0.01]))
    robot = SimPuma(
        clock=clock,
        kinematics=Puma560Kinematics(tool_transform(0.1)),
        start_joints=start,
        home=start,
    )
    await robot.connect()
    await run_with_clock(clock, robot.initialize())
    sensor = SimForceSensor(
        cell, robot.snapshot, Puma560Kinematics(tool_transform(0.1)), noise_n=0.0
    )
    ds = DecisionServer(
        [ArmGuard("arm", 1, robot, Puma560Kinematics(tool_transform(0.1)), SafetyLimits())],
        clock=clock,
        operator_token=TOKEN,
    )
    sensor.subscribe(lambda sample: ds.on_force(sample, ds.arms[0]))
    op = ds.join("operator", TOKEN)
    await ds.take_lease(op.id)

    forces = []
    refused = None
    for _ in range(20):  # 2 mm down every 20 ms (0.1 m/s)
        try:
            await ds.cartesian_increment(op.id, np.array([0, 0, -0.002]), np.zeros(3))
        except SafetyStop as exc:
            refused = exc
            break
        for _ in range(20):  # the sensor samples at 1 kHz while the arm moves
            await clock.advance(0.001)
            sample = sensor.sample_at(clock.now())
            assert sample is not None
            forces.append(-sample.values[2])  # tool z points down: the table pushes along −z
    assert refused is not None and "back away" in str(refused)
    assert ds.state().force_limited
    assert forces[0] == pytest.approx(0.0, abs=1e-9)  # free space first
    assert max(forces) > ds.limits.force_limit_n  # it felt the table
    # The arm was stopped: it brakes to rest, pressing the table, within 1 cm.
    await clock.advance(0.5)
    depth = top - robot.pose.position[2]
    assert 0 < depth < 0.01
    # Backing away is allowed, and the force limit clears once the force drops.
    await ds.cartesian_increment(op.id, np.array([0, 0, 0.015]), np.zeros(3))
    await run_with_clock(clock, robot.wait_idle())
    sensor.sample_at(clock.now())
    assert robot.pose.position[2] > top
    assert not ds.state().force_limited
    await ds.cartesian_increment(op.id, np.array([0.002, 0, 0]), np.zeros(3))  # free to move again
