"""A master arm pressing the simulated gripper onto the stiff block, over a delayed
link, with and without the bridge's passivity controller (issue 16).

The server runs on the simulation (block 5·10⁴ N/m unless ``--stiffness``), with the
slow approach after a contact off (contact_speed_m_s 0.25: that rule scales down the
bridge's moves toward the block but not away from it, so the arm ratchets off the block
and the contact this measures never lasts); the simulated master (a 0.2 kg handle held
by a hand that is a ``--hand-stiffness`` spring) drives it through the master-arm
bridge over the priority channel. The hand grips after 0.5 s 2 cm above the block,
goes down at 2 cm/s to 5 mm above it, then at 5 mm/s to ``--press-mm`` below the
block's top, and holds there for the rest of ``--seconds``: a contact of about 10 s.
The round trip is the bridge's own injected delay (half on the commands, half on the
forces, with ``--jitter-ms`` on each half), so no network namespace is needed. The
block's push is rendered on the device at 1/20.

    python -m bench.master_contact [--json] [--rtts 0,50,100,200,400] [--seconds 12.5]
    python -m bench.master_contact --contact-rule   # the slow approach after a contact

For each round trip, with passivity ("passivity") and without ("none"):

- ``peak_n``: the largest contact force (the force limit is 60 N);
- ``limit_trips``: force-limit stops (samples crossing 60 N upward);
- ``energy_j``: the most energy the master's port gave back beyond what was put in
  (the passivity observer's deficit, at the device; with passivity on the controller
  pays it back each millisecond, so it stays at one step's worth);
- ``oscillation``: RMS (N) of the contact force band-passed to 0.5–20 Hz over the hold
  (after the first contact + 1 s); ``crossings_hz``: how often that band crosses zero;
- ``drift_mm``: at the end, how far the arm's tool moved minus how far the handle moved
  (motion scale 1): what the bridge lost between master and slave;
- ``damped_j``: what the passivity controller dissipated.

Goals (issue 16), printed beside the figures: with passivity at 200 ms, no trip, no
sustained oscillation (``oscillation`` ≤ 2 N), ``energy_j`` ≤ 0.01 J, ``drift_mm`` ≤ 5;
without, at 200 ms, it oscillates (> 2 N) or trips.

``--contact-rule`` runs the earlier comparison instead (no delay): the slow approach
after a contact (contact_speed_m_s 0.02) against none (0.25 m/s), 3 runs each.
"""

from __future__ import annotations

import json
import secrets
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx
import numpy as np

from backend.master.bridge import BridgeSettings, MasterBridge
from backend.master.cli import open_link
from bench.common import emit, machine, parser, serve_for_bench
from drivers.base import FloatArray, ForceSample
from drivers.master.sim import SimMaster

FORCE_LIMIT_N = 60.0
START_ABOVE_M = 0.02
SPEED_M_S = 0.02  # the approach, down to SLOW_ABOVE_M above the block's top
SLOW_ABOVE_M = 0.005
SLOW_M_S = 0.005  # then, as a careful operator near a contact (≈ 1 mm per 200 ms)
OSCILLATION_GOAL_N = 2.0
ENERGY_GOAL_J = 0.01
DRIFT_GOAL_MM = 5.0


def pressing_hand(press_m: float) -> Callable[[float], tuple[FloatArray, bool]]:
    """Grips after 0.5 s, goes down at 2 cm/s to 5 mm above the block's top (which is
    2 cm below the start), on at 5 mm/s to ``press_m`` below the top, then holds."""
    fast = START_ABOVE_M - SLOW_ABOVE_M
    t_fast = fast / SPEED_M_S
    depth = START_ABOVE_M + press_m

    def hand(t: float) -> tuple[FloatArray, bool]:
        if t < 0.5:
            return np.zeros(3), False
        s = t - 0.5
        z = SPEED_M_S * s if s < t_fast else fast + SLOW_M_S * (s - t_fast)
        return np.array([0.0, 0.0, -min(z, depth)]), True

    return hand


def contact_rule_hand(t: float) -> tuple[FloatArray, bool]:
    if t < 0.5:
        return np.zeros(3), False
    return np.array([0.0, 0.0, -0.02 * min(t - 0.5, 3.0)]), True


def band(values: FloatArray, rate_hz: float) -> FloatArray:
    """0.5–20 Hz: the signal minus its 2 s moving average, then a 25 ms moving average."""

    def smooth(x: FloatArray, n: int) -> FloatArray:
        n = max(1, min(n, len(x)))
        return np.convolve(x, np.ones(n) / n, mode="same")

    return smooth(values - smooth(values, int(2.0 * rate_hz)), int(0.025 * rate_hz))


def one_run(
    *,
    rtt_s: float,
    passivity: bool,
    seconds: float,
    press_m: float,
    hand_stiffness: float,
    stiffness: float,
    jitter_s: float = 0.0,
    contact_speed: float | None = 0.25,
    hand: Callable[[float], tuple[FloatArray, bool]] | None = None,
) -> dict[str, Any]:
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_HOME_POSE": "qn",
        "TELEROBOT_BLOCK_STIFFNESS_N_M": str(stiffness),
        "TELEROBOT_PRIORITY_PORT": "0",
    }
    if contact_speed is not None:
        env["TELEROBOT_CONTACT_SPEED_M_S"] = str(contact_speed)
    with serve_for_bench(env=env) as (_, base):
        api = httpx.Client(base_url=base + "api/v1/", headers={"Authorization": f"Bearer {token}"})
        deadline = time.monotonic() + 30
        while api.get("robot/state").json()["status"] != "READY":
            assert time.monotonic() < deadline, "the simulated arm never became ready"
            time.sleep(0.1)
        block = next(b for b in api.get("workcell").json()["boxes"] if b["name"] == "block")
        top = block["centre"][2] + block["size"][2] / 2
        api.headers["X-Client-Id"] = api.post("lease", json={"name": "setup"}).json()["client_id"]
        api.post(
            "robot/move",
            json={
                "space": "cartesian",
                "mode": "absolute",
                "position": [*block["centre"][:2], top + START_ABOVE_M],
            },
        ).raise_for_status()
        api.delete("lease")
        start = np.array(api.get("robot/state").json()["position"], dtype=float)
        device = SimMaster(hand or pressing_hand(press_m), hand_stiffness_n_m=hand_stiffness)
        link = open_link(base, token)
        settings = BridgeSettings(
            force_scale=0.05, passivity=passivity, delay_rtt_s=rtt_s, delay_jitter_s=jitter_s
        )
        bridge = MasterBridge(device, link, settings)
        forces: list[tuple[float, float]] = []  # (sensor time, |F|)
        lock = threading.Lock()

        def keep(sample: ForceSample, received: float) -> None:
            with lock:
                forces.append((sample.time, float(np.linalg.norm(sample.values[:3]))))

        bridge.on_sample = keep
        bridge.start()
        p0 = device.position.copy()
        try:
            time.sleep(seconds)
        finally:
            bridge.stop()
            link.close()
        moved_master = device.position - p0
        end = np.array(api.get("robot/state").json()["position"], dtype=float)
        safety = api.get("safety").json()
    with lock:
        f = np.array([v for _, v in forces])
        t = np.array([s for s, _ in forces])
    touching = np.nonzero(f > 1.0)[0]
    hold = f[touching[0] + 1000 :] if len(touching) else np.array([])
    b = band(hold, 1000.0) if len(hold) > 100 else np.zeros(1)
    crossings = np.sum(np.signbit(b[1:]) != np.signbit(b[:-1])) if len(b) > 1 else 0
    above = f > FORCE_LIMIT_N
    pc = bridge.passivity
    return {
        "peak_n": float(f.max()) if len(f) else 0.0,
        "limit_trips": int(np.sum(above[1:] & ~above[:-1]) + int(above[0])) if len(f) else 0,
        "energy_j": pc.generated,
        "oscillation": float(np.sqrt(np.mean(b**2))),
        "crossings_hz": float(crossings / (len(hold) / 1000.0)) if len(hold) else 0.0,
        "drift_mm": float(np.linalg.norm((end - start) - moved_master) * 1000.0),
        "damped_j": pc.dissipated,
        "contact_s": float(t[-1] - t[touching[0]]) if len(touching) else 0.0,
        "mean_force_n": float(np.mean(hold)) if len(hold) else 0.0,
        "estop_at_end": bool(safety.get("estop")),
        "samples": len(f),
        # (for --contact-rule)
        "depth_mm": max(0.0, (top - end[2]) * 1000.0),
    }


def sweep(args: Any) -> dict[str, Any]:
    figures: dict[str, Any] = {}
    for rtt_ms in [int(x) for x in args.rtts.split(",")]:
        row: dict[str, Any] = {}
        for label, on in (("passivity", True), ("none", False)):
            r = one_run(
                rtt_s=rtt_ms / 1000.0,
                passivity=on,
                seconds=args.seconds,
                press_m=args.press_mm / 1000.0,
                hand_stiffness=args.hand_stiffness,
                stiffness=args.stiffness,
                jitter_s=args.jitter_ms / 1000.0,
            )
            row[label] = r
            print(
                f"rtt {rtt_ms:>3} ms {label:<9} peak {r['peak_n']:6.1f} N · trips"
                f" {r['limit_trips']} · energy {r['energy_j']:.4f} J · oscillation"
                f" {r['oscillation']:.2f} N ({r['crossings_hz']:.1f}/s) · drift"
                f" {r['drift_mm']:.1f} mm · damped {r['damped_j']:.3f} J",
                flush=True,
            )
        figures[f"rtt_{rtt_ms}"] = row
    if "rtt_200" in figures:
        on, off = figures["rtt_200"]["passivity"], figures["rtt_200"]["none"]
        figures["goals"] = {
            "passivity_200_no_trips": on["limit_trips"] == 0,
            "passivity_200_no_oscillation": on["oscillation"] <= OSCILLATION_GOAL_N,
            "passivity_200_energy_bounded": on["energy_j"] <= ENERGY_GOAL_J,
            "passivity_200_drift_le_5mm": on["drift_mm"] <= DRIFT_GOAL_MM,
            "none_200_oscillates_or_trips": off["oscillation"] > OSCILLATION_GOAL_N
            or off["limit_trips"] > 0,
        }
    figures["setup"] = {
        "block_stiffness_n_m": args.stiffness,
        "hand_stiffness_n_m": args.hand_stiffness,
        "press_mm": args.press_mm,
        "seconds": args.seconds,
        "jitter_ms": args.jitter_ms,
        "force_scale": 0.05,
    }
    return figures


def contact_rule(args: Any) -> dict[str, Any]:
    figures: dict[str, Any] = {}
    for label, speed in (("with", 0.02), ("without", 0.25)):
        runs = [
            one_run(
                rtt_s=0.0,
                passivity=True,
                seconds=6.0,
                press_m=0.0,
                hand_stiffness=400.0,
                stiffness=args.stiffness,
                contact_speed=speed,
                hand=contact_rule_hand,
            )
            for _ in range(3)
        ]
        for key, name in (("peak_n", "peak_force_n"), ("depth_mm", "depth_mm"),
                          ("limit_trips", "trips")):  # fmt: skip
            values = [r[key] for r in runs]
            figures[f"{label}_{name}_median"] = float(np.median(values))
            figures[f"{label}_{name}_runs"] = values
    emit({k: v for k, v in figures.items() if not isinstance(v, list)}, False)
    return figures


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--rtts", default="0,50,100,200,400", help="round trips (ms)")
    p.add_argument("--seconds", type=float, default=12.5, help="per run")
    p.add_argument("--press-mm", type=float, default=2.0, help="the hand's target below the top")
    p.add_argument("--hand-stiffness", type=float, default=400.0, help="N/m")
    p.add_argument("--stiffness", type=float, default=5.0e4, help="the block's, N/m")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="σ on each half of the delay")
    p.add_argument("--contact-rule", action="store_true", help="the earlier comparison")
    args = p.parse_args()
    figures = contact_rule(args) if args.contact_rule else sweep(args)
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
