"""A master arm pressing the simulated gripper onto the stiff block (5·10⁴ N/m): how
hard the arm strikes it, with and without the slow approach after a contact.

The server runs on the simulation; the simulated master (a hand that grips after
0.5 s and pushes down 2 cm/s for 3 s, with the block's push rendered on the device
at 1/20) drives it through the master-arm bridge over the priority channel, from
2 cm above the block, for 6 s. Every force sample the bridge receives is kept.

    python -m bench.master_contact [--json] [--runs 3]

peak_force_n: the largest contact force of the run (the force limit is 60 N).
depth_mm: how far the tool went below the block's top (state at 50 Hz).
trips: force-limit stops (samples crossing 60 N upward).
"without" runs set contact_speed_m_s to the full speed limit (0.25 m/s): the rule off.
"""

from __future__ import annotations

import json
import secrets
import time

import httpx
import numpy as np

from backend.master.bridge import BridgeSettings, MasterBridge
from backend.master.cli import open_link
from bench.common import emit, machine, parser, serve_for_bench
from drivers.base import FloatArray, ForceSample
from drivers.master.sim import SimMaster

FORCE_LIMIT_N = 60.0


def hand(t: float) -> tuple[FloatArray, bool]:
    if t < 0.5:
        return np.zeros(3), False
    return np.array([0.0, 0.0, -0.02 * min(t - 0.5, 3.0)]), True


def one_run(contact_speed: float) -> dict[str, float]:
    token = secrets.token_hex(16)
    env = {
        "TELEROBOT_OPERATOR_TOKEN": token,
        "TELEROBOT_HOME_POSE": "qn",
        "TELEROBOT_CONTACT_SPEED_M_S": str(contact_speed),
    }
    with serve_for_bench(env=env) as (_, base):
        api = httpx.Client(base_url=base + "api/v1/", headers={"Authorization": f"Bearer {token}"})
        deadline = time.monotonic() + 30
        while api.get("robot/state").json()["status"] != "READY":
            assert time.monotonic() < deadline, "the simulated arm never became ready"
            time.sleep(0.1)
        block = next(b for b in api.get("workcell").json()["boxes"] if b["name"] == "block")
        top = block["centre"][2] + block["size"][2] / 2
        api.headers["X-Client-Id"] = api.post("lease", json={"name": "setup"}).json()["client_id"]
        r = api.post(
            "robot/move",
            json={
                "space": "cartesian",
                "mode": "absolute",
                "position": [*block["centre"][:2], top + 0.02],
            },
        )
        r.raise_for_status()
        api.delete("lease")
        link = open_link(base, token)
        bridge = MasterBridge(SimMaster(hand), link, BridgeSettings(force_scale=0.05))
        forces: list[float] = []
        on_force = link.on_force
        assert on_force is not None

        def keep(sample: ForceSample, received: float) -> None:
            forces.append(float(np.linalg.norm(sample.values[:3])))
            on_force(sample, received)

        link.on_force = keep
        heights: list[float] = []
        bridge.start()
        try:
            t0 = time.monotonic()
            while time.monotonic() - t0 < 6.0:
                heights.append(api.get("robot/state").json()["position"][2])
                time.sleep(0.02)
        finally:
            bridge.stop()
            link.close()
    f = np.array(forces)
    above = f > FORCE_LIMIT_N
    return {
        "peak_force_n": float(f.max()),
        "depth_mm": max(0.0, (top - min(heights)) * 1000.0),
        "trips": int(np.sum(above[1:] & ~above[:-1]) + int(above[0])),
        "samples": len(f),
    }


def main() -> None:
    p = parser(__doc__ or "")
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    figures: dict[str, float | int | list[float]] = {}
    for label, speed in (("with", 0.02), ("without", 0.25)):
        runs = [one_run(speed) for _ in range(args.runs)]
        for key in ("peak_force_n", "depth_mm", "trips"):
            values = [r[key] for r in runs]
            figures[f"{label}_{key}_median"] = float(np.median(values))
            figures[f"{label}_{key}_runs"] = values
        figures[f"{label}_samples_min"] = min(r["samples"] for r in runs)
    emit({k: v for k, v in figures.items() if not isinstance(v, list)}, False)
    if args.json:
        print(json.dumps({**figures, "machine": machine()}))


if __name__ == "__main__":
    main()
