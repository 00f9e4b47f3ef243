"""A master arm pressing the simulated gripper onto the stiff block, over a delayed
link, with the bridge's passivity controller on both sides of the link (the two-port,
the default), at the master only (the one-port), and without.

The server runs on the simulation (block 5·10⁴ N/m unless ``--stiffness``), with its
slow approach after a contact on (the arm owes a master the motion that rule holds
back, so the two work together); the simulated master (a 0.2 kg handle held
by a hand that is a ``--hand-stiffness`` spring) drives it through the master-arm
bridge over the priority channel. The hand grips after 0.5 s 2 cm above the block,
goes down at 2 cm/s to 5 mm above it, then at 5 mm/s to ``--press-mm`` below the
block's top, and holds there for the rest of ``--seconds``: a contact of about 10 s.
The round trip is the bridge's own injected delay (half on the commands, half on the
forces, with ``--jitter-ms`` on each half), so no network namespace is needed. The
block's push is rendered on the device at 1/20.

    python -m bench.master_contact [--json] [--rtts 0,50,100,200,400,700] [--seconds 12.5]
        [--busy-core]   # stress-ng --cpu 1 meanwhile: a machine also doing something else
    python -m bench.master_contact --contact-rule   # the slow approach after a contact
    python -m bench.master_contact --links wan,mobile  # through harness.netem's link instead

With ``--links`` the delay is a real (emulated) link's instead of the injected one: the
server in the pair's server namespace, the bridge in the client's (its forces as UDP
datagrams, thinned on loss), one server per profile, JSON ``link_<name>``.

For each round trip, with the two-port ("passivity"), the one-port ("one_port") and
without ("none"), in real time and again in virtual time (``virtual_time``):

- ``peak_n``: the largest contact force (the force limit is 60 N);
- ``limit_trips``: force-limit stops (samples crossing 60 N upward);
- ``energy_j``: the most energy the master's port gave back beyond what was put in
  (the passivity observer's deficit, at the device; with passivity on the controller
  pays it back each millisecond, so it stays at one step's worth);
- ``oscillation``: RMS (N) of the contact force band-passed to 0.5–20 Hz over the hold
  (after the first contact + 1 s); ``crossings_hz``: how often that band crosses zero;
- ``contact_s``: from the first contact (> 1 N) to the end; ``lift_offs``: how often
  the force fell back below 1 N after it (the tool bouncing off the block);
- ``drift_mm``: at the end, how far the arm's tool moved minus how far the handle moved
  (motion scale 1): what the bridge lost between master and slave;
- ``damped_j``: what the passivity controller dissipated;
- (real time only) ``forces_per_s`` and ``commands_per_s``: force samples the bridge
  received and commands it sent, a second; ``overruns``: its 1 kHz loop's cycles
  skipped for being more than 50 ms late.

- (real time only) ``tick_gap_ms_p99``/``_max``: the bridge's 1 kHz loop's period as
  it ran; ``force_age_ms_p50``/``_p99``: how old the force it rendered was (sensor time
  to use, on the server's clock). The velocity estimate and the energy books take
  each tick's measured step (the device's own read times), so a late tick makes a
  longer step, not wrong books: ``tick_gap_ms_max`` is also their longest step.

Goals, each for real and virtual time (``goals``): with passivity, no limit
trip and ``oscillation`` ≤ 2 N at every round trip up to 200 ms, no trip at 400 and
700 ms, ``drift_mm`` ≤ 5 everywhere; without, at 200 ms, it oscillates (> 2 N),
trips, or loses the press (mean force < 2 N).

``--contact-rule`` runs the earlier comparison instead (no delay): the slow approach
after a contact (contact_speed_m_s 0.02) against none (0.25 m/s), 3 runs each.

``--virtual`` runs only the sweep in virtual time (``stepped_press``: the same server
parts, bridge, master and hand on one stepped clock, in this process). Its figures are
the same on every machine; tests/test_passivity.py asserts on them. The real-time
sweep is the end-to-end figure: it adds how punctually this machine runs the bridge's,
the sensor's and the server's 1 kHz loops, and the link. ``--modes`` picks which of
passivity, one_port, none to run. The press itself (the hand, the bridge, both clocks'
runs) is harness/master_press.py's.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import subprocess
import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.common import busy_core, emit, machine, parser
from harness.master_press import MODES, one_run, press, server_env, stepped_run
from harness.servers import serve_for_bench
from telerobot.drivers.base import FloatArray

OSCILLATION_GOAL_N = 2.0
ENERGY_GOAL_J = 0.01
DRIFT_GOAL_MM = 5.0
LOST_PRESS_N = 2.0  # a mean force over the hold below this: the press was lost


def contact_rule_hand(t: float) -> tuple[FloatArray, bool]:
    if t < 0.5:
        return np.zeros(3), False
    return np.array([0.0, 0.0, -0.02 * min(t - 0.5, 3.0)]), True


RTTS_MS = (0, 50, 100, 200, 400, 700)


def over_links(args: Any) -> dict[str, Any]:
    """The same press with the server behind an emulated link (harness.netem): the bridge
    runs in the client's namespace, its forces come as datagrams, no injected delay."""
    from harness.netem import REPO, NetemPair, emulator_available

    why = emulator_available()
    if why is not None:
        raise SystemExit(f"no link emulator here: {why}")
    figures: dict[str, Any] = {}
    token = secrets.token_hex(16)
    for name in [n.strip() for n in args.links.split(",") if n.strip()]:
        with (
            NetemPair(name) as pair,
            serve_for_bench(
                "--host", pair.server_addr, env=server_env(token, args.stiffness),
                prefix=pair.server_prefix,
            ) as (_, base),
        ):  # fmt: skip
            row: dict[str, Any] = {}
            for label in ("passivity", "none"):
                done = subprocess.run(
                    [*pair.client_prefix, sys.executable, "-m", "bench.master_contact",
                     "--role", "press", "--base", base, "--mode", label,
                     "--seconds", str(args.seconds), "--press-mm", str(args.press_mm),
                     "--hand-stiffness", str(args.hand_stiffness)],
                    capture_output=True, text=True, timeout=args.seconds + 120,
                    env={**os.environ, "BENCH_TOKEN": token}, cwd=str(REPO),
                )  # fmt: skip
                lines = [ln for ln in done.stdout.splitlines() if ln.startswith("{")]
                if done.returncode != 0 or not lines:
                    raise RuntimeError(f"the press on {name} failed:\n{done.stderr[-3000:]}")
                row[label] = r = json.loads(lines[-1])
                print(f"{name:<7}" + line(label, r), flush=True)
            figures[f"link_{name}"] = row
    return figures


def line(label: str, r: dict[str, Any]) -> str:
    return (
        f" {label:<9} peak {r['peak_n']:6.1f} N · trips {r['limit_trips']} · energy"
        f" {r['energy_j']:.4f} J · oscillation {r['oscillation']:.2f} N"
        f" ({r['crossings_hz']:.1f}/s) · drift {r['drift_mm']:.1f} mm · damped"
        f" {r['damped_j']:.3f} J · ping {r['ping_rtt_ms']:.0f} ms"
    )


def sweep(args: Any, run: Callable[..., dict[str, Any]], label: str) -> dict[str, Any]:
    """Every round trip × mode, with ``run`` (``one_run`` or ``stepped_run``)."""
    figures: dict[str, Any] = {}
    modes = [m_.strip() for m_ in args.modes.split(",") if m_.strip()]
    for rtt_ms in [int(x) for x in args.rtts.split(",")]:
        row: dict[str, Any] = {}
        for mode in modes:
            r = run(
                rtt_s=rtt_ms / 1000.0,
                passivity=mode,
                seconds=args.seconds,
                press_m=args.press_mm / 1000.0,
                hand_stiffness=args.hand_stiffness,
                stiffness=args.stiffness,
                jitter_s=args.jitter_ms / 1000.0,
            )
            row[mode] = r
            print(f"{label:<7} rtt {rtt_ms:>3} ms" + line(mode, r), flush=True)
        figures[f"rtt_{rtt_ms}"] = row
    figures["goals"] = goals(figures)
    return figures


def goals(figures: dict[str, Any]) -> dict[str, bool | None]:
    """The goals (this module's docstring) over one sweep (None: not run)."""

    def runs(mode: str, upto: int | None = None, at: tuple[int, ...] = ()) -> list[Any]:
        out = []
        for key, row in figures.items():
            if not key.startswith("rtt_") or mode not in row:
                continue
            rtt = int(key[4:])
            if (upto is not None and rtt <= upto) or rtt in at:
                out.append(row[mode])
        return out

    def every(rs: list[Any], ok: Callable[[Any], bool]) -> bool | None:
        return all(ok(r) for r in rs) if rs else None

    low, high = runs("passivity", upto=200), runs("passivity", at=(400, 700))
    everywhere = runs("passivity", upto=10_000)
    off = runs("none", at=(200,))
    return {
        "passivity_le_200_no_trips": every(low, lambda r: r["limit_trips"] == 0),
        "passivity_le_200_oscillation_le_2": every(
            low, lambda r: r["oscillation"] <= OSCILLATION_GOAL_N
        ),
        "passivity_400_700_no_trips": every(high, lambda r: r["limit_trips"] == 0),
        "passivity_drift_le_5mm": every(everywhere, lambda r: r["drift_mm"] <= DRIFT_GOAL_MM),
        # Without passivity the press fails at 200 ms: it rings or trips (the slow approach
        # off), or is thrown off the block and kept off (the rule on: the ratchet).
        "none_200_rings_trips_or_loses_the_press": every(
            off,
            lambda r: (
                r["oscillation"] > OSCILLATION_GOAL_N
                or r["limit_trips"] > 0
                or r["mean_force_n"] < LOST_PRESS_N
            ),
        ),
    }


def setup(args: Any) -> dict[str, Any]:
    return {
        "block_stiffness_n_m": args.stiffness,
        "hand_stiffness_n_m": args.hand_stiffness,
        "press_mm": args.press_mm,
        "seconds": args.seconds,
        "jitter_ms": args.jitter_ms,
        "force_scale": 0.05,
        "contact_speed_m_s": "the server's default (the rule on)",
    }


def contact_rule(args: Any) -> dict[str, Any]:
    figures: dict[str, Any] = {}
    for label, speed in (("with", 0.02), ("without", 0.25)):
        runs = [
            one_run(
                rtt_s=0.0,
                passivity="passivity",
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
    p.add_argument("--rtts", default=",".join(map(str, RTTS_MS)), help="round trips (ms)")
    p.add_argument("--modes", default=",".join(MODES), help="of " + ", ".join(MODES))
    p.add_argument("--seconds", type=float, default=12.5, help="per run")
    p.add_argument("--press-mm", type=float, default=2.0, help="the hand's target below the top")
    p.add_argument("--hand-stiffness", type=float, default=400.0, help="N/m")
    p.add_argument("--stiffness", type=float, default=5.0e4, help="the block's, N/m")
    p.add_argument("--jitter-ms", type=float, default=0.0, help="σ on each half of the delay")
    p.add_argument("--contact-rule", action="store_true", help="the earlier comparison")
    p.add_argument("--busy-core", action="store_true", help="stress-ng --cpu 1 meanwhile")
    p.add_argument(
        "--virtual", action="store_true", help="only the sweep in virtual time (stepped_press)"
    )
    p.add_argument(
        "--links", help="instead of injected delays: these harness.netem profiles, e.g. wan,mobile"
    )
    p.add_argument("--role", choices=("press",), help=argparse.SUPPRESS)
    p.add_argument("--base", help=argparse.SUPPRESS)
    p.add_argument("--mode", choices=tuple(MODES), help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.role == "press":  # one press, in the client's namespace (--links)
        r = press(
            args.base, os.environ["BENCH_TOKEN"], rtt_s=0.0, passivity=args.mode,
            seconds=args.seconds, press_m=args.press_mm / 1000.0,
            hand_stiffness=args.hand_stiffness,
        )  # fmt: skip
        print(json.dumps(r))
        return
    if args.contact_rule:
        figures = contact_rule(args)
    elif args.links:
        figures = over_links(args)
    elif args.virtual:
        figures = {"virtual_time": sweep(args, stepped_run, "virtual")}
    else:
        with busy_core(args.busy_core):
            figures = sweep(args, one_run, "real")
        figures["virtual_time"] = sweep(args, stepped_run, "virtual")
    figures["setup"] = {**setup(args), "busy_core": args.busy_core}
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
