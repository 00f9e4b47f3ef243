"""The shared link emulator (harness/netem.py), measured with real processes and
sockets between its two network namespaces: a profile's delay is one-way (a round trip
takes twice it), its loss is what the probes lose, its rate caps a UDP flood, an outage
drops everything for its length and the link comes back, and nothing is left behind.

Timing is the subject here, so these tests measure real time; bounds are statistical
(binomial bands of ±4.5 σ for loss, the median's spread for delays) with a margin for a
shared, loaded 2-core machine. They skip, saying why, where the kernel refuses network
namespaces or has neither netem nor the TAP redirect the user-space forwarder needs."""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import threading
import time
from collections.abc import Iterator

import pytest

from harness.netem import (
    PROFILES,
    LinkMeasurement,
    NetemPair,
    Profile,
    emulator_available,
    measure_link,
    measure_rate,
    netem_args,
    netem_available,
)

_why_not = emulator_available()  # also says when namespaces themselves are refused
needs_emulator = pytest.mark.skipif(
    _why_not is not None, reason=f"no link emulator here: {_why_not}"
)


@pytest.fixture(scope="module")
def pair() -> Iterator[NetemPair]:
    with NetemPair() as p:
        yield p


@pytest.fixture
def link(pair: NetemPair) -> Iterator[NetemPair]:
    yield pair
    pair.up()
    pair.apply("lan")


def _band(p: float, n: int, sigmas: float = 4.5) -> tuple[float, float]:
    """Where a binomial share with probability ``p`` over ``n`` trials falls."""
    sd = math.sqrt(p * (1 - p) / n)
    return max(0.0, p - sigmas * sd), p + sigmas * sd


# ---------------------------------------------------------------- no system needed
def test_the_profiles_are_the_ones_issue_15_names() -> None:
    figures = {
        name: (p.delay_ms, p.jitter_ms, p.loss_pct, p.rate_mbit) for name, p in PROFILES.items()
    }
    assert figures == {
        "lan": (0, 0, 0, None),
        "wifi": (5, 3, 0.5, None),
        "wan": (40, 10, 1, 20),
        "mobile": (80, 30, 2, 4),
        "bad": (150, 50, 5, 2),
    }
    assert not PROFILES["lan"].shaped and PROFILES["lan"].cut().shaped


def test_netem_keeps_jittered_packets_in_order_by_always_setting_a_rate() -> None:
    assert netem_args(PROFILES["mobile"]) == [
        "netem", "limit", "1000", "delay", "80ms", "30ms", "distribution", "normal",
        "loss", "random", "2%", "rate", "4mbit",
    ]  # fmt: skip
    wifi = netem_args(PROFILES["wifi"])
    assert wifi[wifi.index("rate") + 1] == "10000mbit"  # no cap, but netem's in-order rule
    assert netem_args(PROFILES["wan"].cut())[-4:] == ["random", "100%", "rate", "20mbit"]


# ---------------------------------------------------------------- measured
@needs_emulator
def test_wifi_round_trip_is_twice_the_one_way_delay(link: NetemPair) -> None:
    # What the link adds on this machine now (the processes' wake-ups, the forwarder):
    # the baseline the profile's delay is added to, so that a loaded or slower machine
    # moves both (the emulator's figures are bench.netem's).
    base = measure_link(link, probes=200, interval_s=0.005)
    link.apply("wifi")
    m = measure_link(link, probes=400, interval_s=0.005)
    print(f"wifi ({link.backend}): {m}\nlan baseline: {base}")
    # A loaded machine only adds: more room above than below.
    assert 2 * 5 - 1.5 <= m.rtt_p50_ms <= 2 * 5 + 5 + base.rtt_p90_ms, (m, base)
    assert 5 - 1 <= m.up_p50_ms <= 5 + 3 + base.rtt_p90_ms, (m, base)
    assert 5 - 1 <= m.down_p50_ms <= 5 + 3 + base.rtt_p90_ms, (m, base)
    assert m.loss_round_trip <= _band(1 - 0.995**2, m.probes)[1], m
    assert m.reordered == 0, m


@needs_emulator
def test_mobile_delay_and_loss_are_what_the_profile_says(link: NetemPair) -> None:
    base = measure_link(link, probes=200, interval_s=0.005)  # as in the wifi test
    link.apply("mobile")
    # Sparse probes (50 ms apart, > 1.5 σ of jitter) see the profile's delay: the FIFO
    # rarely holds one behind the one before (a simulation of the rule: +2 ms median).
    sparse = measure_link(link, probes=120, interval_s=0.05)
    # Dense ones (1 kHz, like the force stream) give the loss its statistics, and show
    # what a FIFO link does to a stream denser than its jitter: in order, but later.
    dense = measure_link(link, probes=2000, interval_s=0.001)
    print(f"mobile ({link.backend}) sparse: {sparse}\nmobile dense: {dense}")
    # The median of 120 draws with σ = 30 ms (42 ms a round trip) is good to ~±5 ms a
    # standard error; a loaded machine only adds (its own round trip, ``base``).
    extra = base.rtt_p90_ms
    assert -25 <= sparse.rtt_p50_ms - 2 * 80 <= 35 + extra, (sparse, base)
    assert -15 <= sparse.up_p50_ms - 80 <= 22 + extra, (sparse, base)
    assert -15 <= sparse.down_p50_ms - 80 <= 22 + extra, (sparse, base)
    low, high = _band(0.02, dense.probes)
    assert low <= dense.loss_up <= high, dense
    assert low <= dense.loss_down <= high, dense
    assert dense.reordered == 0, dense
    assert dense.up_p50_ms > sparse.up_p50_ms + 15, (dense, sparse)


def _lost_during(m: LinkMeasurement, start: float, end: float) -> tuple[int, int]:
    """Probes sent in [start, end]: how many, and how many reached the server."""
    inside = [seq for seq, t in enumerate(m.sent) if start <= t <= end]
    return len(inside), sum(seq in m.echoed_at for seq in inside)


def _answered_share(m: LinkMeasurement, start: float, end: float) -> tuple[int, float]:
    inside = [seq for seq, t in enumerate(m.sent) if start <= t <= end]
    return len(inside), sum(seq in m.answered for seq in inside) / max(1, len(inside))


@needs_emulator
@pytest.mark.parametrize("profile", ["lan", "wifi"])
def test_an_outage_drops_everything_for_its_length_then_the_link_recovers(
    link: NetemPair, profile: str
) -> None:
    link.apply(profile)
    result: list[LinkMeasurement] = []
    flowing = threading.Event()
    prober = threading.Thread(
        target=lambda: result.append(
            measure_link(link, probes=700, interval_s=0.005, started=flowing.set)
        )
    )
    prober.start()
    assert flowing.wait(timeout=20)
    time.sleep(0.8)  # probes flow before the outage…
    going_down = time.monotonic()
    link.down()
    went_down = time.monotonic()
    time.sleep(1.0)
    came_up = time.monotonic()
    link.up()
    back_up = time.monotonic()  # …and after it
    prober.join(timeout=30)
    m = result[0]
    sent, arrived = _lost_during(m, went_down, came_up)
    assert sent >= 150 and arrived == 0, (sent, arrived)
    # The gap in answers is printed, not asserted: it is the outage's length only while
    # the forwarder keeps up. With a core busy, a forwarder's backlog of probes sent
    # before the outage was still answered all through it (longest gap 32 ms), though
    # nothing sent inside it got through: that, above, is the behaviour.
    received = sorted(r for _, _, r in m.answered.values())
    gap = max(b - a for a, b in itertools.pairwise(received))
    print(f"{profile} ({link.backend}): answers stopped for {gap * 1000:.0f} ms")
    # Away from the outage's edges (probes a loaded forwarder still held then are lost
    # with it), nearly every probe was answered.
    before, share_before = _answered_share(m, 0, going_down - 0.25)
    after, share_after = _answered_share(m, back_up + 0.25, math.inf)
    assert before >= 40 and share_before >= 0.9, (before, share_before)
    assert after >= 40 and share_after >= 0.9, (after, share_after)


@needs_emulator
def test_mobiles_rate_caps_a_udp_flood_and_wifi_does_not(link: NetemPair) -> None:
    link.apply("mobile")
    capped = measure_rate(link, offered_mbit=6.0)
    link.apply("wifi")
    free = measure_rate(link, offered_mbit=6.0)
    print(f"6 Mbit/s offered: mobile {capped}\nwifi {free}")
    assert capped.sent_mbit >= 5.0, capped  # the sender did exceed the cap
    assert 3.5 <= capped.frame_mbit <= 4.5, capped
    # What wifi (no cap) lets through of the same flood: the cap is mobile's, not the
    # emulator's own limit.
    assert free.received_mbit >= 0.95 * free.sent_mbit, free


@needs_emulator
def test_two_pairs_at_once_do_not_collide_and_leave_nothing_behind() -> None:
    fixed = Profile("fixed", delay_ms=20)
    with NetemPair(fixed) as a, NetemPair("lan") as b:
        assert {a.server_ns, a.client_ns}.isdisjoint({b.server_ns, b.client_ns})
        ma = measure_link(a, probes=20, interval_s=0.005)
        mb = measure_link(b, probes=20, interval_s=0.005)
        # The fastest probe says which link it crossed, however loaded the machine is.
        rtt_a = min(r - s for s, _, r in ma.answered.values())
        rtt_b = min(r - s for s, _, r in mb.answered.values())
        assert rtt_a >= 0.040 > 0.020 > rtt_b, (ma, mb)
        names = {a.server_ns, a.client_ns, b.server_ns, b.client_ns}
        forwarder = a.forwarder_pid
        assert forwarder is not None or a.backend == "netem"
    with pytest.raises(RuntimeError, match="inside"), NetemPair("mobile") as c:
        names |= {c.server_ns, c.client_ns}
        raise RuntimeError("inside")
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert not any(name in listed for name in names), listed
    assert forwarder is None or not os.path.exists(f"/proc/{forwarder}")


@needs_emulator
@pytest.mark.skipif(netem_available() is not None, reason=f"{netem_available()}")
def test_the_netem_backend_installs_netem_on_both_ends() -> None:
    with NetemPair("wan", backend="netem") as pair:
        for ns, dev in ((pair.server_ns, pair.server_dev), (pair.client_ns, pair.client_dev)):
            shown = subprocess.run(
                ["tc", "-n", ns, "qdisc", "show", "dev", dev], capture_output=True, text=True
            ).stdout
            assert "netem" in shown and "delay 40ms" in shown and "loss 1%" in shown, shown
        m = measure_link(pair, probes=100, interval_s=0.015)
        assert abs(m.rtt_p50_ms - 80) <= 15, m
