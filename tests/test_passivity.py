"""Time-domain passivity in the master bridge: the observer and controller
on known signals, the bridge's injected delay, its settings, and the whole loop (the
simulated server, the bridge, the master) with a 200 ms round trip in virtual time:
stable with passivity, ringing without."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from telerobot.client.master.bridge import BridgeSettings, MasterBridge
from telerobot.client.master.passivity import PassivityController, PassivitySettings
from telerobot.drivers.base import ForceSample, InvalidCommand
from telerobot.drivers.master.sim import SimMaster

DT = 0.001


def drive(
    pc: PassivityController, force_of: Callable[[float, np.ndarray, np.ndarray], np.ndarray],
    seconds: float = 4.0, amplitude: float = 0.01, hz: float = 2.0,
) -> tuple[list[float], float]:  # fmt: skip
    """Move the port sinusoidally along z; ``force_of(t, x, v)`` is what the port asks.
    Returns the observed energy after each step and the energy the port's output
    (after the controller) put out in all."""
    energies, out = [], 0.0
    for n in range(int(seconds / DT)):
        t = n * DT
        w = 2 * math.pi * hz
        x = np.array([0.0, 0.0, amplitude * math.sin(w * t)])
        v = np.array([0.0, 0.0, amplitude * w * math.cos(w * t)])
        f = pc.step(force_of(t, x, v), v, DT)
        out += float(f @ v) * DT
        energies.append(pc.energy)
    return energies, out


def test_a_passive_spring_damper_never_triggers_the_controller() -> None:
    pc = PassivityController()
    energies, _ = drive(pc, lambda t, x, v: -500.0 * x - 2.0 * v)
    assert min(energies) >= -1e-9
    assert pc.dissipated == 0.0 and pc.generated <= 1e-9 and pc.damping == 0.0


def test_an_active_element_is_damped_to_zero_net_energy() -> None:
    # A negative damper: pushes along the motion, making energy all the time.
    pc = PassivityController()
    energies, out = drive(pc, lambda t, x, v: 3.0 * v)
    assert min(energies) >= -1e-9  # paid back within the step, every step
    assert out == pytest.approx(0.0, abs=1e-6)  # nothing net left the port
    assert pc.dissipated > 0.01
    # Observed only (switched off): the same element's energy runs away, and the
    # observer says by how much.
    off = PassivityController(PassivitySettings(enabled=False))
    energies, out = drive(off, lambda t, x, v: 3.0 * v)
    assert (
        out > 0.01 and min(energies) == pytest.approx(-out) and off.generated == pytest.approx(out)
    )
    assert off.dissipated == 0.0


def test_a_delayed_spring_makes_energy_and_the_controller_takes_it_back() -> None:
    # f(t) = −k·x(t − T): a stiff contact seen through a 100 ms delay.
    k, T, hz, a = 2500.0, 0.1, 2.0, 0.002

    def delayed(t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.array([0.0, 0.0, -k * a * math.sin(2 * math.pi * hz * (t - T))])

    off = PassivityController(PassivitySettings(enabled=False))
    drive(off, delayed, amplitude=a, hz=hz)
    assert off.generated > 0.01  # the delay turned the spring into a source
    on = PassivityController()
    energies, out = drive(on, delayed, amplitude=a, hz=hz)
    assert min(energies) >= -1e-9 and out <= 1e-6


def test_the_damper_is_capped_and_counts_when_it_is() -> None:
    pc = PassivityController(PassivitySettings(max_damping_n_s_m=1.0))
    energies, _ = drive(pc, lambda t, x, v: 50.0 * v)
    assert pc.saturated > 0 and min(energies) < -0.01  # what the cap left owed is shown
    assert pc.damping <= 1.0


def test_no_damper_when_still() -> None:
    pc = PassivityController()
    pc.energy = -1.0  # owed, but the handle does not move: α would be infinite
    f = pc.step(np.array([0.0, 0.0, 1.0]), np.zeros(3), DT)
    assert f.tolist() == [0.0, 0.0, 1.0] and pc.damping == 0.0


def test_velocity_is_estimated_from_positions_and_filtered() -> None:
    pc = PassivityController(PassivitySettings(velocity_cutoff_hz=50.0))
    for n in range(200):
        v, dt = pc.velocity_from(n * DT, np.array([0.0, 0.0, 0.02 * n * DT]))
    assert dt == pytest.approx(DT) and v[2] == pytest.approx(0.02, rel=1e-3)


@pytest.mark.parametrize(
    "bad",
    [
        {"max_damping_n_s_m": 0.0},
        {"max_damping_n_s_m": math.nan},
        {"delay_rtt_s": -0.1},
        {"delay_rtt_s": math.nan},
        {"delay_rtt_s": 3.0},
        {"delay_jitter_s": math.inf},
    ],
)
def test_bad_passivity_and_delay_settings_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(InvalidCommand, match=next(iter(bad)).split("_")[0]):
        BridgeSettings(**bad).check()  # type: ignore[arg-type]


class FakeLink:
    """What the bridge needs of a PriorityLink, recording the commands it sends."""

    def __init__(self) -> None:
        self.offset = 0.0
        self.closed_reason = None
        self.autonomy = "off"  # no policy's supervision
        self.sent: list[tuple[float, tuple[float, ...]]] = []
        self.energies: list[tuple[float, float, float]] = []
        self.now = 0.0
        self.on_force = self.on_state = self.on_reply = None

    def cartesian(
        self, dX: tuple[float, ...], rotvec: tuple[float, ...], frame: object = None
    ) -> int:
        self.sent.append((self.now, dX))
        return len(self.sent)

    def energy(self, e_in: float, e_out: float) -> int:
        self.energies.append((self.now, e_in, e_out))
        return len(self.energies)

    def heartbeat(self) -> None:
        pass


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_injected_round_trip_delays_commands_and_forces_by_half_each() -> None:
    clock = Clock()
    hand_z = [0.0]
    device = SimMaster(lambda t: (np.array([0.0, 0.0, hand_z[0]]), True), time_source=clock)
    link = FakeLink()
    bridge = MasterBridge(
        device,
        link,
        BridgeSettings(delay_rtt_s=0.2, force_scale=0.1),
        time_source=clock,  # type: ignore[arg-type]
    )
    bridge.flags = 1  # YOU_HAVE_CONTROL: commands go out
    device.open()
    moved_at = None
    for n in range(600):
        clock.t = n * DT
        link.now = clock.t
        if n == 100:
            hand_z[0] = -0.005  # the hand moves at 0.1 s
            moved_at = clock.t
        bridge.tick()
    assert moved_at is not None and link.sent
    # (Gripped, the two-port bridge sends an increment every period, still or not,
    # each after its ENERGY: the first went out half the round trip after the start.)
    assert 0.1 - 0.002 <= link.sent[0][0] <= 0.1 + 0.012
    assert len(link.energies) == len(link.sent)
    first = next(t for t, dx in link.sent if any(dx))
    assert 0.1 + 0.1 - 0.002 <= first <= 0.1 + 0.1 + 0.012  # half the round trip (+ a period)
    # A force sample received at 0.6 s is rendered from 0.7 s, not before.
    bridge._on_force(ForceSample(1, 0.6, (0.0, 0.0, 10.0, 0.0, 0.0, 0.0)), 0.6)
    assert not np.any(bridge.remote_force_device_frame(0.699))
    assert bridge.remote_force_device_frame(0.7)[2] == pytest.approx(1.0)


def test_jitter_keeps_the_order() -> None:
    clock = Clock()
    bridge = MasterBridge(
        SimMaster(time_source=clock), FakeLink(),  # type: ignore[arg-type]
        BridgeSettings(delay_rtt_s=0.1, delay_jitter_s=0.05), time_source=clock,
    )  # fmt: skip
    dues = [bridge._due("in", n * DT) for n in range(2000)]
    assert all(b >= a for a, b in itertools.pairwise(dues))
    assert 0.04 < float(np.median(np.array(dues) - np.arange(2000) * DT)) < 0.15


# The whole loop at 200 and 700 ms round trips, in virtual time (harness.master_press's
# stepped_press: the server's simulated arm, 5·10⁴ N/m block, force sensor and
# DecisionServer with its slow approach after a contact, the bridge with its injected
# delay and passivity controller, the simulated master and hand, all on one stepped
# clock). Deterministic: the same figures on any machine. The real-time figure
# (threads at 1 kHz, a served server, the link) is `python -m bench.master_contact`'s.
PRESS = {"seconds": 7.0, "press_m": 0.002, "hand_stiffness": 400.0, "stiffness": 5.0e4}


@pytest.fixture(scope="module")
def presses() -> dict[tuple[int, str], dict[str, Any]]:
    from harness.master_press import stepped_run

    runs = {
        (rtt, mode): stepped_run(rtt_s=rtt / 1000, passivity=mode, **PRESS)
        for rtt, mode in ((200, "passivity"), (200, "none"), (700, "passivity"), (700, "one_port"))
    }
    runs[(200, "undamped")] = stepped_run(
        rtt_s=0.2, passivity="passivity", contact_damping=0.0, **PRESS
    )
    return runs


@pytest.mark.parametrize("rtt", [200, 700])
def test_with_the_two_port_the_press_holds_on_the_block(
    presses: dict[tuple[int, str], dict[str, Any]], rtt: int
) -> None:
    on = presses[(rtt, "passivity")]
    assert on["contact_s"] > 3.0 and on["lift_offs"] == 0, on  # it pressed, and stayed
    # The arm puts into the block no more than the operator put in: no impact from
    # the increments sent before the force came back, no ringing, no force limit;
    # the force settles near the hand's press (400 N/m × 2 mm against the block's push
    # at 1/20: ~14 N; less at 700 ms, where less of the press has come through yet: ~4 N).
    assert on["limit_trips"] == 0 and on["peak_n"] < 30.0, on
    assert on["oscillation"] < 2.0, on
    assert 2.0 < on["mean_force_n"] < 20.0, on
    assert on["drift_mm"] < 5.0 and not on["estop_at_end"], on


def test_the_contact_damper_stills_what_passivity_lets_ring(
    presses: dict[tuple[int, str], dict[str, Any]],
) -> None:
    # Passivity bounds the energy the contact gives back, not how long a passive
    # exchange of it rings: at 200 ms the contact swung by ~1.4 N at ~3 Hz without the
    # handle's contact damper, and is still with it (10 N·s/m, the default).
    on, undamped = presses[(200, "passivity")], presses[(200, "undamped")]
    assert undamped["oscillation"] > 0.8, undamped
    assert on["oscillation"] < 0.2, on
    assert abs(on["mean_force_n"] - undamped["mean_force_n"]) < 2.0, (on, undamped)


def test_without_passivity_the_press_is_lost(
    presses: dict[tuple[int, str], dict[str, Any]],
) -> None:
    on, off = presses[(200, "passivity")], presses[(200, "none")]
    summary = f"with {on}\nwithout {off}"
    # The delayed spring pushes the handle back harder than the hand pressed it: the
    # tool strikes the block (~56 N, by the 200 ms of increments sent blind), is thrown
    # off, and the slow approach after a contact keeps it off (without the two-port the
    # arm owes the master nothing: the ratchet) — or, with that rule off, it rings and
    # trips the limit (bench.master_contact). Either way no press.
    assert off["peak_n"] > 3 * on["peak_n"] and off["lift_offs"] >= 1, summary
    assert off["mean_force_n"] < 2.0 or off["limit_trips"] > 0, summary
    assert off["energy_j"] > 10 * on["energy_j"] and off["drift_mm"] > 5.0, summary


def test_at_700_ms_the_master_alone_cannot_keep_the_arm_off_the_limit(
    presses: dict[tuple[int, str], dict[str, Any]],
) -> None:
    # The one-port (the master's side only) damps the handle but cannot stop what was
    # already sent: the arm drives into the block on 350 ms of increments.
    one = presses[(700, "one_port")]
    assert one["limit_trips"] > 0 or one["peak_n"] > 55.0, one


def test_the_damper_never_reverses_the_handle_on_a_long_step() -> None:
    # A busy machine's 20 ms step: α held that long takes α·h/m of the handle's speed.
    # With the handle's mass known, α ≤ m/h (here 0.2 kg / 20 ms = 10 N·s/m), not the
    # 1000 N·s/m cap that suits a 1 ms step and reversed the handle at 20.
    pc = PassivityController(PassivitySettings(handle_mass_kg=0.2))
    pc.energy = -1.0  # owed
    pc.step(np.zeros(3), np.array([0.0, 0.0, 0.1]), 0.02)
    assert pc.damping == pytest.approx(10.0) and pc.saturated == 1
    # A 1 ms step again: the long one is remembered for a while (slowly forgotten).
    pc.step(np.zeros(3), np.array([0.0, 0.0, 0.1]), 0.001)
    assert pc.damping == pytest.approx(0.2 / (0.02 * 0.99))


def test_the_arms_energy_waiting_in_the_injected_delay_is_bounded() -> None:
    # PORT_ENERGY answers held for the injected round trip: a flood of them keeps the
    # newest 1000, not all.
    from telerobot.client.master.link import Reply

    clock = Clock()
    bridge = MasterBridge(
        SimMaster(time_source=clock), FakeLink(),  # type: ignore[arg-type]
        BridgeSettings(delay_rtt_s=1.0), time_source=clock,
    )  # fmt: skip
    for n in range(1500):
        bridge._on_reply(Reply("PORT_ENERGY", {"seq": n, "e_in": n * 1e-3, "e_out": 0.0}, ""))
    assert len(bridge._arm_energy) == 1000 and bridge._arm_energy[-1][1] == pytest.approx(1.499)
