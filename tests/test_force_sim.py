from __future__ import annotations

import math
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from telerobot.drivers.base import ArmSnapshot, ForceSample, InvalidCommand
from telerobot.drivers.force import sim as sim_module
from telerobot.drivers.force.pipeline import ForcePipeline
from telerobot.drivers.force.sim import SimForceSensor
from telerobot.drivers.robot.puma560.kinematics import NAMED_POSES, Puma560Kinematics
from telerobot.drivers.sim.workcell import default_workcell
from tests.support.puma import TOOL, joints_with_tip_at


class Arm:
    """The state the sensor probes; tests set it directly."""

    def __init__(self, q: np.ndarray, v: np.ndarray | None = None, t: float = 0.0) -> None:
        self.snap = ArmSnapshot(t, q, np.zeros(6) if v is None else v)

    def __call__(self) -> ArmSnapshot:
        return self.snap


def sensor_for(arm: Arm, noise: float = 0.0) -> SimForceSensor:
    return SimForceSensor(default_workcell(), arm, Puma560Kinematics(TOOL), noise_n=noise)


def test_free_space_reads_zero() -> None:
    cell = default_workcell()
    q = joints_with_tip_at(np.array([0.8, 0.2, cell.table.upper[2] + 0.05]))
    assert sensor_for(Arm(q)).read_raw(0.0) == pytest.approx((0,) * 6, abs=1e-9)


def test_pushing_into_the_table_gives_an_upward_force_proportional_to_depth() -> None:
    cell = default_workcell()
    top = cell.table.upper[2]
    readings = []
    for depth in (0.001, 0.002, 0.004):
        q = joints_with_tip_at(np.array([0.8, 0.2, top - depth]))
        readings.append(sensor_for(Arm(q)).read_raw(0.0))
    for depth, r in zip((0.001, 0.002, 0.004), readings, strict=True):
        # Tool z points down, so the table's upward push is −z in the sensor frame.
        assert r[2] == pytest.approx(-cell.table.stiffness * depth, rel=1e-6)
        assert r[0] == pytest.approx(0, abs=1e-6) and r[1] == pytest.approx(0, abs=1e-6)
        assert r[3:] == pytest.approx((0, 0, 0), abs=1e-6)  # force along the tool axis: no torque


def test_side_push_into_the_block_gives_torque_about_the_flange() -> None:
    cell = default_workcell()
    side = cell.block.lower[0]
    q = joints_with_tip_at(
        np.array([side + 0.003, cell.block.centre[1], cell.block.centre[2] + 0.02])
    )
    r = sensor_for(Arm(q)).read_raw(0.0)
    f = np.array(r[:3])
    assert np.linalg.norm(f) == pytest.approx(cell.block.stiffness * 0.003, rel=1e-6)
    # Force applied 0.1 m down the tool axis: |τ| = 0.1 m × |F|, perpendicular to F.
    assert np.linalg.norm(r[3:]) == pytest.approx(0.1 * np.linalg.norm(f), rel=1e-6)
    assert abs(np.dot(f, r[3:])) < 1e-6


def test_damping_resists_the_approach_and_extrapolates_motion() -> None:
    cell = default_workcell()
    q = joints_with_tip_at(np.array([0.8, 0.2, cell.table.upper[2] - 0.002]))
    kin = Puma560Kinematics(TOOL)
    J = kin.jacobian(q)
    qd = np.linalg.lstsq(J, np.array([0, 0, -0.05, 0, 0, 0]), rcond=None)[0]  # tip down at 5 cm/s
    still = sensor_for(Arm(q)).read_raw(0.0)[2]
    moving = sensor_for(Arm(q, qd)).read_raw(0.0)[2]
    assert moving == pytest.approx(still - cell.table.damping * 0.05, rel=1e-4)
    later = sensor_for(Arm(q, qd)).read_raw(0.01)[2]  # 10 ms on: 0.5 mm deeper
    assert later == pytest.approx(moving - cell.table.stiffness * 0.0005, rel=1e-3)


def test_tare_threshold_and_filter() -> None:
    p = ForcePipeline(1000.0)
    assert p.process((1, 2, 3, 0, 0, 0)) == (1, 2, 3, 0, 0, 0)
    p.tare()
    assert p.process((1, 2, 3, 0, 0, 0)) == (0, 0, 0, 0, 0, 0)
    p.threshold = 0.5
    assert p.process((1.2, 2, 3, 0, 0, 0)) is None  # a change of 0.2 is withheld
    assert p.process((1.6, 2, 3, 0, 0, 0)) == pytest.approx((0.6, 0, 0, 0, 0, 0))
    p.threshold = 0.0
    p.filter_cutoff_hz = 10.0
    out = p.process((11.6, 2, 3, 0, 0, 0))  # a 10 N step through a 10 Hz low-pass at 1 kHz
    a = 0.001 / (1 / (2 * math.pi * 10) + 0.001)
    assert out is not None and out[0] == pytest.approx(0.6 + 10 * a)


@pytest.mark.parametrize(
    ("setting", "value"),
    [
        ("rate_hz", 0),
        ("rate_hz", math.nan),
        ("threshold", -1),
        ("filter_cutoff_hz", 600.0),
        ("threshold", math.inf),
    ],
)
def test_bad_settings_are_refused(setting: str, value: float) -> None:
    s = sensor_for(Arm(NAMED_POSES["qn"]))
    with pytest.raises(InvalidCommand):
        setattr(s, setting, value)


class ThreadTime:
    """Virtual time for the sampling thread: its sleeps advance the clock at once."""

    def __init__(self) -> None:
        self.t = 100.0

    def now(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.t += seconds


class StallingTime(ThreadTime):
    """Virtual time whose sampling thread is held up once, for ``stall_s``, at ``at``."""

    def __init__(self, at: float, stall_s: float) -> None:
        super().__init__()
        self.at, self.stall_s = at, stall_s

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        if self.t >= self.at and self.stall_s:
            self.t += self.stall_s  # the thread ran this much later than it asked
            self.stall_s = 0.0


def _samples_through_a_stall(monkeypatch: pytest.MonkeyPatch, stall_s: float) -> tuple[
    SimForceSensor, list[ForceSample]
]:  # fmt: skip
    clock = StallingTime(at=100.05, stall_s=stall_s)
    monkeypatch.setattr(sim_module, "time", SimpleNamespace(sleep=clock.sleep))
    s = SimForceSensor(
        default_workcell(), Arm(NAMED_POSES["qn"]), Puma560Kinematics(TOOL), noise_n=0.01,
        time_source=clock.now,
    )  # fmt: skip
    got: list[ForceSample] = []
    enough = threading.Event()

    def on_sample(sample: ForceSample) -> None:
        got.append(sample)
        if len(got) >= 300:
            enough.set()

    s.subscribe(on_sample)
    s.start()
    assert enough.wait(10.0), "fewer than 300 samples in 10 s"
    s.stop()
    return s, got


def test_sampling_thread_delivers_numbered_samples_at_the_rate(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The real sampling thread on virtual time: the period is exact on any
    # machine. How punctually a busy machine runs the 1 kHz thread is bench.force_stream's.
    s, got = _samples_through_a_stall(monkeypatch, 0.0)  # (no stall)
    assert not s.running
    seqs = [g.seq for g in got]
    assert seqs == list(range(1, len(seqs) + 1))  # threshold 0: every sample, none lost
    span = got[199].time - got[0].time
    assert span == pytest.approx(0.199)  # 199 periods of 1 ms
    assert s.overruns == 0


def test_the_priority_channel_gets_each_sample_before_the_subscribers_that_wake_the_loop(
    tmp_path: Path,
) -> None:
    """The datagram leaves before the hub and the decision server are handed the sample
    (each by call_soon_threadsafe, which wakes the event loop's thread to take the GIL
    from the sensor's); subscribed later, it still comes first."""
    from fastapi.testclient import TestClient

    from telerobot.server.app import create_app
    from telerobot.server.services import Services
    from telerobot.server.settings import Settings

    settings = Settings(state_dir=tmp_path, http_port=0, priority_port=0, video=False)
    with TestClient(create_app(settings)) as c:
        services: Services = c.app.state.services  # type: ignore[attr-defined]
        force = services.arms[0].force
        assert isinstance(force, SimForceSensor)
        # (the channel's own is a partial naming the arm: its fan-out's bound method inside)
        order = [getattr(getattr(cb, "func", cb), "__self__", None) for cb in force._subscribers]
        assert order[0] is services.priority.fanout and len(order) >= 3
        s = sensor_for(Arm(NAMED_POSES["qn"]))
        got: list[str] = []
        s.subscribe(lambda _: got.append("later"))
        s.subscribe(lambda _: got.append("first"), first=True)
        s._deliver(1, 0.0, np.zeros(6))
        assert got == ["first", "later"]


def test_samples_keep_their_1khz_times_through_a_short_stall(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Held up for 20.5 ms, the simulation stamped the samples it then took at once
    with the time it took them: a 20 ms gap, then 20 samples µs apart (66 ms gaps and
    bursts in a quiet machine's recordings). Each sample now has its own slot's time."""
    s, got = _samples_through_a_stall(monkeypatch, 0.0205)
    got = got[:300]
    assert [g.seq for g in got] == list(range(1, 301))
    np.testing.assert_allclose(np.diff([g.time for g in got]), 0.001, atol=1e-9)
    assert s.overruns == 0


def test_samples_lost_in_a_long_stall_are_counted_and_skipped_in_the_sequence(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Held up for 150 ms (more than it catches up), the slots are lost: the sequence
    numbers skip them, as a real sensor's lost packets do, and ``overruns`` counts them
    (the simulation had lost them without a trace in the numbers)."""
    s, got = _samples_through_a_stall(monkeypatch, 0.1505)
    got = got[:300]
    gaps = np.diff([g.seq for g in got])
    assert sorted(set(gaps.tolist())) == [1, 151]
    assert s.overruns == 150
    np.testing.assert_allclose(
        np.diff([g.time for g in got]), np.diff([g.seq for g in got]) * 0.001, atol=1e-9
    )
