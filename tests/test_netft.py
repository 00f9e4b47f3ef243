"""The Net F/T driver against its emulator, over real UDP sockets on loopback."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterator

import pytest

from telerobot.drivers.base import ForceSample, InvalidCommand
from telerobot.drivers.force import netft_protocol as rdt
from telerobot.drivers.force.netft import NetFtSensor, parse_address
from telerobot.drivers.force.netft_emulator import NetFtEmulator
from tests.support import until

PUSH = (1.5, -2.0, 10.0, 0.1, -0.2, 0.05)


@pytest.fixture
def emulator() -> Iterator[NetFtEmulator]:
    with NetFtEmulator(signal=lambda t: PUSH, counts_per_force=1e6, counts_per_torque=1e6) as emu:
        yield emu


@pytest.fixture
def sensor(emulator: NetFtEmulator) -> Iterator[NetFtSensor]:
    s = NetFtSensor(emulator.url, counts_per_force=1e6, counts_per_torque=1e6, silence_s=0.2)
    samples: list[ForceSample] = []
    s.subscribe(samples.append)
    s.samples = samples  # type: ignore[attr-defined]
    s.start()
    yield s
    s.stop()


def test_it_streams_counts_as_newtons_with_the_rdt_sequence(
    sensor: NetFtSensor, emulator: NetFtEmulator
) -> None:
    samples: list[ForceSample] = sensor.samples  # type: ignore[attr-defined]
    until(lambda: len(samples) >= 200)
    assert emulator.requests[0] == rdt.CMD_STREAM
    assert samples[-1].values == pytest.approx(PUSH, abs=1e-6)
    seqs = [s.seq for s in samples[:200]]
    assert seqs == list(range(seqs[0], seqs[0] + 200))  # consecutive: nothing lost
    assert sensor.lost == 0 and sensor.bad_packets == 0
    times = [s.time for s in samples[:200]]
    assert times == sorted(times)
    sensor.stop()
    until(lambda: not emulator.streaming)  # stop tells the sensor to stop streaming
    assert emulator.requests[-1] == rdt.CMD_STOP


def test_bias_asks_the_sensor_to_zero_itself(sensor: NetFtSensor, emulator: NetFtEmulator) -> None:
    samples: list[ForceSample] = sensor.samples  # type: ignore[attr-defined]
    until(lambda: len(samples) > 10)
    sensor.tare()
    until(lambda: rdt.CMD_BIAS in emulator.requests)
    n = len(samples)
    until(lambda: len(samples) > n + 10)
    assert samples[-1].values == pytest.approx((0,) * 6, abs=1e-6)


def test_gaps_in_the_sequence_are_counted_as_lost(
    sensor: NetFtSensor, emulator: NetFtEmulator
) -> None:
    samples: list[ForceSample] = sensor.samples  # type: ignore[attr-defined]
    until(lambda: len(samples) > 10)
    emulator.drop(7)
    n = len(samples)
    until(lambda: len(samples) > n + 20)
    assert sensor.lost == 7
    seqs = [s.seq for s in samples]
    assert max(b - a for a, b in itertools.pairwise(seqs)) == 8


def test_short_and_malformed_packets_are_counted_and_dropped(
    sensor: NetFtSensor, emulator: NetFtEmulator
) -> None:
    samples: list[ForceSample] = sensor.samples  # type: ignore[attr-defined]
    until(lambda: len(samples) > 10)
    emulator.send_raw(b"\x12\x34")
    emulator.send_raw(b"x" * 40)
    until(lambda: sensor.bad_packets == 2)
    n = len(samples)
    until(lambda: len(samples) > n + 10)  # the stream goes on
    assert all(s.values == pytest.approx(PUSH, abs=1e-6) for s in samples)


def test_repeated_and_older_packets_are_stale_and_not_delivered() -> None:
    s = NetFtSensor("127.0.0.1:9")
    got: list[ForceSample] = []
    s.subscribe(got.append)
    counts = (1_000_000, 0, 0, 0, 0, 0)
    for seq in (10, 11, 11, 9, 12, 2**32 - 1):
        s.on_packet(rdt.Record(seq, seq, 0, counts).pack(), float(seq))
    assert [g.seq for g in got] == [10, 11, 12]
    assert s.stale == 3 and s.lost == 0
    s.on_packet(rdt.Record(15, 15, 0, counts).pack(), 15.0)
    assert s.lost == 2
    # The sequence wraps at 2³²: 0 follows 2³² − 1.
    w = NetFtSensor("127.0.0.1:9")
    w.on_packet(rdt.Record(2**32 - 1, 0, 0, counts).pack(), 0.0)
    w.on_packet(rdt.Record(0, 1, 0, counts).pack(), 0.0)
    assert w.lost == 0 and w.stale == 0 and w.received == 2


def test_a_silent_sensor_is_reported_and_streaming_resumes_by_itself(
    sensor: NetFtSensor, emulator: NetFtEmulator
) -> None:
    samples: list[ForceSample] = sensor.samples  # type: ignore[attr-defined]
    until(lambda: len(samples) > 10)
    emulator.reboot()  # forgets its client, as a power cycle would
    until(lambda: sensor.silences == 1)
    assert sensor.last_error is not None and "no data" in sensor.last_error
    assert emulator.url in sensor.last_error  # it says which sensor
    n = len(samples)
    until(lambda: len(samples) > n + 10)  # the driver asked again: data flows
    assert sensor.error is None
    assert emulator.requests.count(rdt.CMD_STREAM) >= 2


def test_addresses_and_calibration_are_checked() -> None:
    assert parse_address("10.0.0.5") == ("10.0.0.5", rdt.RDT_PORT)
    assert parse_address("sensor.local:5000") == ("sensor.local", 5000)
    for bad in ("", ":49152", "host:0", "host:99999", "host:port"):
        with pytest.raises(InvalidCommand, match="HOST:PORT"):
            parse_address(bad)
    with pytest.raises(InvalidCommand, match="positive"):
        NetFtSensor("127.0.0.1", counts_per_force=0)


def test_subscribers_are_called_from_the_receiving_thread(sensor: NetFtSensor) -> None:
    threads: set[str] = set()
    sensor.subscribe(lambda s: threads.add(threading.current_thread().name))
    until(lambda: bool(threads))
    assert threads == {"netft-receiver"}


def test_an_unknown_host_is_reported_not_raised() -> None:
    s = NetFtSensor("no-such-sensor.invalid:49152")
    s.start()  # the server must come up even so
    try:
        until(lambda: s.error is not None)
        assert "cannot reach the Net F/T at udp://no-such-sensor.invalid:49152" in str(s.error)
        assert s.latest is None
    finally:
        s.stop()
