"""Safety owns its loop (docs/architecture.md, rule 15): with no transport at all — no hub,
no /ws, no priority channel — the DecisionServer still stops the arm on a force
above the limit and on a silent lease holder."""

from __future__ import annotations

import asyncio
import threading

import numpy as np
import pytest

from telerobot.drivers.base import ForceSample
from telerobot.drivers.clock import ManualClock
from telerobot.drivers.force.sampled import SampledForceSensor
from telerobot.server.control.decision import DecisionServer
from telerobot.server.control.errors import NotAllowed, SafetyStop
from tests.support import TOKEN, until_async
from tests.support.decision import make


class ThreadedForceSource(SampledForceSensor):
    """A force sensor whose samples are delivered from a thread of its own, as every
    real one does; the test says what it measures."""

    def __init__(self) -> None:
        super().__init__(1000.0)

    def _run(self) -> None:
        self._stop.wait()

    def press(self, values: tuple[float, ...], seq: int = 1) -> None:
        thread = threading.Thread(target=self._deliver, args=(seq, 0.0, values))
        thread.start()
        thread.join()


async def started_with_a_sensor() -> tuple[DecisionServer, ThreadedForceSource]:
    """A DecisionServer on the simulated arm, running its own loop, fed by a sensor
    thread, and no transport at all."""
    ds, _ = await make(ManualClock())
    sensor = ThreadedForceSource()
    ds.arms[0].force = sensor
    ds.start()
    return ds, sensor


async def test_the_force_limit_stops_the_arm_with_no_transport_running() -> None:
    ds, sensor = await started_with_a_sensor()
    try:
        op = ds.join("script", TOKEN)
        await ds.take_lease(op.id)
        await ds.cartesian_increment(op.id, np.array([0.005, 0, 0]), np.zeros(3))
        sensor.press((0.0, 0.0, 100.0, 0.0, 0.0, 0.0))
        # The sample crosses from the sensor's thread to the loop (a deadline, not a
        # figure: the reaction time is the sensor's period plus a tick).
        await until_async(lambda: ds.state().force_limited)
        refused = None
        try:
            await ds.cartesian_increment(op.id, np.array([0, 0, -0.005]), np.zeros(3))
        except SafetyStop as exc:
            refused = exc
        assert refused is not None and "back away" in str(refused)
    finally:
        await ds.stop()
    assert sensor._subscribers == []  # stop() unsubscribed


async def test_the_dead_man_lapses_a_silent_lease_with_no_transport_running() -> None:
    clock = ManualClock()
    ds, robot = await make(clock)
    ds.start()
    try:
        op = ds.join("script", TOKEN)
        await ds.take_lease(op.id)
        await clock.advance(ds.limits.deadman_timeout_s / 2)
        assert ds.lease_holder == op.id
        for _ in range(20):  # 0.4 s of silence, in the watchdog's own ticks
            await clock.advance(ds.limits.tick_s)
        assert ds.state().halted and ds.lease_holder == op.id  # stopped; lease kept
        for _ in range(int(ds.limits.lease_grace_s / ds.limits.tick_s)):
            await clock.advance(ds.limits.tick_s)
        assert ds.lease_holder is None
        assert robot.status.value in ("READY", "MOVING")  # stopped, not broken
    finally:
        await ds.stop()


async def test_a_sample_below_the_limit_changes_nothing() -> None:
    ds, sensor = await started_with_a_sensor()
    try:
        sensor.press((0.0, 0.0, 5.0, 0.0, 0.0, 0.0))
        await asyncio.sleep(0.02)
        assert not ds.state().force_limited
        assert isinstance(sensor.latest, ForceSample)
    finally:
        await ds.stop()


async def test_the_client_table_is_bounded_and_idle_rest_clients_are_forgotten() -> None:
    clock = ManualClock()
    ds, _ = await make(clock)
    ds.clients.max_clients = 4
    scripts = [ds.join(f"script {i}", TOKEN, idle_expiry_s=60.0) for i in range(3)]
    watcher = ds.join("ws observer", None)  # a connection: never expires
    refused = None
    try:
        ds.join("one too many", None)
    except NotAllowed as exc:
        refused = exc
    assert refused is not None and "4 clients" in str(refused)
    await ds.take_lease(scripts[0].id)
    ds.start()
    try:
        for _ in range(int(61 / ds.limits.tick_s) + 60):
            await clock.advance(ds.limits.tick_s)
            ds.seen(scripts[0].id)  # the lease holder keeps talking
        late = ds.join("a later script", TOKEN, idle_expiry_s=60.0)
        assert (
            ds.clients.get(late.id) and ds.clients.get(watcher.id) and ds.clients.get(scripts[0].id)
        )
        for gone in scripts[1:]:
            with pytest.raises(NotAllowed):
                ds.clients.get(gone.id)
    finally:
        await ds.stop()


async def test_a_scripted_lease_idles_between_moves_but_jogging_keeps_the_fast_dead_man() -> None:
    clock = ManualClock()
    ds, robot = await make(clock)
    ds.start()
    try:
        script = ds.join("script", TOKEN, lease_idle_s=5.0)
        await ds.take_lease(script.id)
        q = robot.joints.copy()
        q[0] += 0.05
        await ds.move_joints(script.id, q)  # a bounded absolute move
        for _ in range(100):  # 2 s with no request: a person reading the screen
            await clock.advance(ds.limits.tick_s)
        assert ds.lease_holder == script.id
        await ds.cartesian_increment(script.id, np.array([0.002, 0, 0]), np.zeros(3))
        for _ in range(15):  # 0.3 s of silence after jogging: the fast dead-man
            await clock.advance(ds.limits.tick_s)
        assert ds.state().halted
        for _ in range(int(ds.limits.lease_grace_s / ds.limits.tick_s)):  # and its grace
            await clock.advance(ds.limits.tick_s)
        assert ds.lease_holder is None
        await ds.take_lease(script.id)
        await ds.move_joints(script.id, q)
        for _ in range(int(5.2 / ds.limits.tick_s)):  # past its idle timeout
            await clock.advance(ds.limits.tick_s)
        assert ds.lease_holder is None
    finally:
        await ds.stop()
