"""A Net F/T that restarts counts its RDT sequence from the start again: the driver
follows the new sequence at once and says so, over real UDP sockets on loopback
(it used to drop as "stale" as many packets as it had received before)."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest

from telerobot.drivers.base import ForceSample
from telerobot.drivers.force import netft_protocol as rdt
from telerobot.drivers.force.netft import REORDER_WINDOW, NetFtSensor
from telerobot.drivers.force.netft_emulator import NetFtEmulator
from tests.support import until

PUSH = (1.5, -2.0, 10.0, 0.1, -0.2, 0.05)
COUNTS = (1_000_000, 0, 0, 0, 0, 0)


@pytest.fixture
def emulator() -> Iterator[NetFtEmulator]:
    with NetFtEmulator(signal=lambda t: PUSH, counts_per_force=1e6, counts_per_torque=1e6) as emu:
        yield emu


@pytest.fixture
def sensor(emulator: NetFtEmulator) -> Iterator[NetFtSensor]:
    s = NetFtSensor(emulator.url, counts_per_force=1e6, counts_per_torque=1e6, silence_s=0.2)
    s.start()
    yield s
    s.stop()


def _collect(sensor: NetFtSensor) -> list[ForceSample]:
    samples: list[ForceSample] = []
    sensor.subscribe(samples.append)
    return samples


def test_a_sequence_that_jumps_far_back_is_a_restart_followed_at_once(
    sensor: NetFtSensor, emulator: NetFtEmulator, caplog: pytest.LogCaptureFixture
) -> None:
    samples = _collect(sensor)
    # Far enough in that a restart goes back past any re-ordering.
    until(lambda: bool(samples) and samples[-1].seq > 2 * REORDER_WINDOW)
    n = len(samples)
    with caplog.at_level(logging.WARNING, logger="telerobot.drivers.force.netft"):
        emulator.restart_sequence()  # streams on, counting from 1 again
        until(lambda: sum(s.seq < REORDER_WINDOW for s in samples[n:]) > 10)
    # The first packets of the new sequence are delivered, not dropped as stale: the
    # old driver dropped every one until the new count passed the old (> 512 here).
    after = [s.seq for s in samples[n:] if s.seq < REORDER_WINDOW]
    assert after[0] <= 3, after[:5]
    assert after == sorted(after)
    assert sensor.stale == 0 and sensor.restarts == 1
    assert sensor.counters["restarts"] == 1  # what GET /api/v1/force shows
    said = [r.getMessage() for r in caplog.records if "restarted" in r.getMessage()]
    assert len(said) == 1 and emulator.url in said[0], said
    assert samples[-1].values == pytest.approx(PUSH, abs=1e-6)


def test_a_rebooted_sensor_asked_to_stream_again_is_followed_from_its_new_start(
    sensor: NetFtSensor, emulator: NetFtEmulator
) -> None:
    """A power cycle: silence, the driver asks again, the sensor counts from 1. Its old
    count was short (within the re-ordering window), yet nothing is taken for stale."""
    samples = _collect(sensor)
    until(lambda: len(samples) > 10)
    emulator.reboot()  # forgets its client and its count
    until(lambda: sensor.silences == 1)
    n = len(samples)
    until(lambda: len(samples) > n + 10)  # the driver asked again: data flows
    assert samples[n].seq < 10, [s.seq for s in samples[n : n + 5]]
    assert sensor.stale == 0 and sensor.restarts == 1
    assert sensor.error is None


def test_a_small_reorder_is_still_stale_and_a_far_jump_back_a_restart() -> None:
    s = NetFtSensor("127.0.0.1:9")
    got: list[int] = []
    s.subscribe(lambda sample: got.append(sample.seq))
    top = 10 * REORDER_WINDOW
    for seq in (top, top - 1, top - REORDER_WINDOW, top + 1):
        s.on_packet(rdt.Record(seq, seq, 0, COUNTS).pack(), 0.0)
    assert got == [top, top + 1] and s.stale == 2 and s.restarts == 0
    # One further back than any re-ordering: the sensor restarted.
    s.on_packet(rdt.Record(top - REORDER_WINDOW, 1, 0, COUNTS).pack(), 0.0)
    assert got[-1] == top - REORDER_WINDOW and s.restarts == 1
    for seq in (1, 2, 3):  # a restart to 1, then on from there: none lost, none stale
        s.on_packet(rdt.Record(seq, seq, 0, COUNTS).pack(), 0.0)
    assert got[-3:] == [1, 2, 3] and s.restarts == 2 and s.stale == 2 and s.lost == 0
    s.on_packet(rdt.Record(2, 2, 0, COUNTS).pack(), 0.0)  # and re-ordering is judged anew
    assert s.stale == 3 and got[-1] == 3


def test_a_restart_after_a_bias_says_to_tare_again(
    sensor: NetFtSensor, emulator: NetFtEmulator, caplog: pytest.LogCaptureFixture
) -> None:
    samples = _collect(sensor)
    until(lambda: bool(samples) and samples[-1].seq > 2 * REORDER_WINDOW)
    sensor.tare()
    until(lambda: rdt.CMD_BIAS in emulator.requests)
    with caplog.at_level(logging.WARNING, logger="telerobot.drivers.force.netft"):
        emulator.restart_sequence()  # a power dip: the sensor's bias is gone too
        until(lambda: sensor.restarts == 1)
    said = [r.getMessage() for r in caplog.records if "restarted" in r.getMessage()]
    assert said and "tare it again" in said[0], said
